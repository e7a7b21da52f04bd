"""`slidewatch detect`: compare two DSMs and write the detected landslides as GeoJSON."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import click

from worker.pipeline.atomic import atomic_path
from worker.pipeline.comparison import (
    METHOD_SUMMARIES,
    METHODS,
    ComparisonOptions,
    compare_dsms,
    default_method,
)
from worker.pipeline.errors import InputError

EXIT_INPUT_ERROR = 2


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
    type=click.Choice(METHODS),
    default=None,
    help="Default: threshold (the API's and the map's default too). "
    + " ".join(f"{name}: {METHOD_SUMMARIES[name]}" for name in METHODS),
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
def detect(
    pre_path: Path,
    post_path: Path,
    out_path: Path,
    method: str | None,
    model: str | None,
    work_dir: Path | None,
    min_area: float | None,
    lod: float | None,
) -> None:
    """Detect landslides between two DSMs; print a one-line JSON summary."""
    options = ComparisonOptions(method=method or default_method())
    if model is not None:
        if options.method != "cnn":
            click.echo("error: --model needs --method cnn", err=True)
            raise SystemExit(EXIT_INPUT_ERROR)
        options.cnn.model = model
    if min_area is not None:
        options.vectorize.min_area_m2 = min_area
        options.score.min_area_m2 = min_area
        options.cnn.min_area_m2 = min_area
    if lod is not None:
        options.difference.lod_m = lod
    temporary = None
    if work_dir is None:
        temporary = tempfile.mkdtemp(prefix="slidewatch-detect-")
        work_dir = Path(temporary)
    try:
        result = compare_dsms(pre_path, post_path, work_dir, options)
        with atomic_path(out_path) as tmp:
            shutil.copyfile(result.detections_path, tmp)
    except InputError as exc:
        click.echo(f"error: {exc}", err=True)
        raise SystemExit(EXIT_INPUT_ERROR) from exc
    finally:
        if temporary is not None:
            shutil.rmtree(temporary, ignore_errors=True)
    click.echo(json.dumps(result.summary()))
