"""`slidewatch detect`: compare two DSMs and write the detected landslides as GeoJSON."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import click

from worker.pipeline.atomic import atomic_path
from worker.pipeline.comparison import COMMON_STAGES, ComparisonOptions, compare_dsms
from worker.pipeline.detection_methods import (
    default_method,
    detection_method,
    detection_methods,
    method_names,
)
from worker.pipeline.errors import InputError
from worker.pipeline.vectorize import VectorizeOptions

EXIT_INPUT_ERROR = 2


class MethodChoice(click.Choice):
    """The registered detection methods, read when the command runs (not at import), so a
    method registered by a module named in the settings is offered too."""

    def __init__(self) -> None:
        super().__init__(())

    @property  # type: ignore[override]
    def choices(self) -> tuple[str, ...]:
        return method_names()

    @choices.setter
    def choices(self, _value: object) -> None:
        pass


class StageChoice(click.Choice):
    """Every comparison stage: the common ones and each method's detection stage."""

    def __init__(self) -> None:
        super().__init__(())

    @property  # type: ignore[override]
    def choices(self) -> tuple[str, ...]:
        return (*(s.name for s in COMMON_STAGES), *(m.stage.name for m in detection_methods()))

    @choices.setter
    def choices(self, _value: object) -> None:
        pass


def _methods_help() -> str:
    lines = [f"{m.name}: {m.summary}" for m in detection_methods()]
    return f"Default: {default_method()} (the API's and the map's default too). " + " ".join(lines)


@click.command("detect")
@click.option(
    "--pre",
    "pre_path",
    required=True,
    type=click.Path(path_type=Path),
    help="DSM of the earlier survey (GeoTIFF).",
)
@click.option(
    "--post",
    "post_path",
    required=True,
    type=click.Path(path_type=Path),
    help="DSM of the later survey (GeoTIFF).",
)
@click.option(
    "--out",
    "out_path",
    required=True,
    type=click.Path(path_type=Path),
    help="Where to write the detections (GeoJSON FeatureCollection).",
)
@click.option(
    "--method",
    type=MethodChoice(),
    default=None,
    help=_methods_help(),
)
@click.option(
    "--model",
    default=None,
    help="cnn: a model card (.json) or weights (.pt) path; default: the shipped model.",
)
@click.option(
    "--work-dir",
    type=click.Path(path_type=Path),
    default=None,
    help="Keep the intermediate rasters here (default: a temporary directory).",
)
@click.option(
    "--min-area", type=float, default=None, help="Smallest detection kept, in square metres."
)
@click.option(
    "--lod",
    type=float,
    default=None,
    help="Fixed level of detection in metres (default: the per-pixel LoD95 of the "
    "error model fitted on stable terrain).",
)
@click.option(
    "--vegetation-cut",
    is_flag=True,
    help="threshold: set aside grass mown between the surveys (for grassland; a slide "
    "inside a mown patch goes with it, so it is off by default).",
)
@click.option(
    "--from-stage",
    type=StageChoice(),
    default=None,
    help="Resume in --work-dir: the stages before this one must have run there.",
)
def detect(
    pre_path: Path,
    post_path: Path,
    out_path: Path,
    method: str | None,
    model: str | None,
    work_dir: Path | None,
    min_area: float | None,
    lod: float | None,
    vegetation_cut: bool,
    from_stage: str | None,
) -> None:
    """Detect landslides between two DSMs; print a one-line JSON summary."""
    options = ComparisonOptions(method=method or default_method())
    chosen = detection_method(options.method)
    if model is not None:
        if not chosen.needs_model:
            click.echo(f"error: --model: the {chosen.name} method runs no model", err=True)
            raise SystemExit(EXIT_INPUT_ERROR)
        options.detection.model = model
    if min_area is not None:
        if not hasattr(options.detection, "min_area_m2"):
            click.echo(f"error: --min-area: the {chosen.name} method has no minimum area", err=True)
            raise SystemExit(EXIT_INPUT_ERROR)
        options.detection.min_area_m2 = min_area
    if lod is not None:
        options.difference.lod_m = lod
    if vegetation_cut:
        if not isinstance(options.detection, VectorizeOptions):
            click.echo(
                f"error: --vegetation-cut: the {chosen.name} method does not set aside mown grass",
                err=True,
            )
            raise SystemExit(EXIT_INPUT_ERROR)
        options.detection.vegetation_cut = True
    if from_stage is not None and work_dir is None:
        click.echo("error: --from-stage needs the --work-dir of the earlier run", err=True)
        raise SystemExit(EXIT_INPUT_ERROR)
    temporary = None
    if work_dir is None:
        temporary = tempfile.mkdtemp(prefix="slidewatch-detect-")
        work_dir = Path(temporary)
    try:
        result = compare_dsms(pre_path, post_path, work_dir, options, from_stage=from_stage)
        with atomic_path(out_path) as tmp:
            shutil.copyfile(result.detections_path, tmp)
    except InputError as exc:
        click.echo(f"error: {exc}", err=True)
        raise SystemExit(EXIT_INPUT_ERROR) from exc
    finally:
        if temporary is not None:
            shutil.rmtree(temporary, ignore_errors=True)
    click.echo(json.dumps(result.summary()))
