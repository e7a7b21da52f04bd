"""The whole DSM comparison: align -> coregister -> difference -> the method's detection stage.

A comparison's pipeline is data (worker/pipeline/stages.py): three stages every method
shares, then the detection stage of its method (worker/pipeline/detection_methods.py):

    threshold   align -> coregister -> difference -> vectorize  (the LoD method, the default)
    scored      align -> coregister -> difference -> score
    cnn         align -> coregister -> difference -> detect

Each stage reads only the caller's two DSMs or files that earlier stages wrote into
`work_dir` (the layout is in comparison_layout.py), and overwrites its own outputs
atomically, so a stage can be re-run on its own (one Celery task per stage).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from worker.pipeline.align import AlignOptions, AlignResult, align
from worker.pipeline.cog import RasterRole
from worker.pipeline.comparison_layout import (
    DETECTIONS,
    DH,
    ERROR_MODEL,
    LOD,
    POST_ALIGNED,
    POST_COREGISTERED,
    PRE_ALIGNED,
    SIGNIFICANCE,
    STABLE_MASK,
    ComparisonContext,
    DetectionMethod,
)
from worker.pipeline.coregister import CoregisterOptions, CoregisterResult, coregister
from worker.pipeline.detection_methods import (
    default_method,
    detection_method,
    detection_methods,
)
from worker.pipeline.difference import DifferenceOptions, DifferenceResult, difference
from worker.pipeline.errors import InputError
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.stages import GEOTIFF, Output, Pipeline, StageSpec

__all__ = [
    "COMMON_STAGES",
    "ComparisonContext",
    "ComparisonOptions",
    "ComparisonResult",
    "compare_dsms",
    "comparison_pipeline",
    "default_method",
    "run_stage",
    "stages_for",
    "summarize",
]


def _align(context: ComparisonContext, progress: ProgressFn) -> AlignResult:
    return align(
        Path(context.pre_path),
        Path(context.post_path),
        context.file(PRE_ALIGNED),
        context.file(POST_ALIGNED),
        context.options.align,
        progress,
    )


def _coregister(context: ComparisonContext, progress: ProgressFn) -> CoregisterResult:
    return coregister(
        context.file(PRE_ALIGNED),
        context.file(POST_ALIGNED),
        context.file(POST_COREGISTERED),
        context.options.coregister,
        progress,
        stable_mask_out=context.file(STABLE_MASK),
    )


def _difference(context: ComparisonContext, progress: ProgressFn) -> DifferenceResult:
    return difference(
        context.file(PRE_ALIGNED),
        context.file(POST_COREGISTERED),
        context.file(DH),
        context.file(SIGNIFICANCE),
        context.options.difference,
        stable_mask_path=context.file(STABLE_MASK),
        progress=progress,
    )


# Weights: shares of the progress bar from measured times (coregistration dominates).
COMMON_STAGES: tuple[StageSpec[ComparisonContext], ...] = (
    StageSpec(
        name="align",
        run=_align,
        help="both DSMs onto one grid",
        outputs=(Output(PRE_ALIGNED), Output(POST_ALIGNED)),
        weight=0.1,
    ),
    StageSpec(
        name="coregister",
        run=_coregister,
        help="post DSM shifted onto pre",
        inputs=(PRE_ALIGNED, POST_ALIGNED),
        outputs=(
            Output(POST_COREGISTERED, "post_coregistered", GEOTIFF, RasterRole.elevation),
            Output(STABLE_MASK),
        ),
        weight=0.65,
    ),
    StageSpec(
        name="difference",
        run=_difference,
        help="Δh and its per-pixel level of detection",
        inputs=(PRE_ALIGNED, POST_COREGISTERED, STABLE_MASK),
        outputs=(
            Output(DH, "dh", GEOTIFF, RasterRole.elevation),
            Output(SIGNIFICANCE, "significance", GEOTIFF, RasterRole.mask),
            # A level in metres is continuous: overviews average it, as elevations.
            Output(LOD, "lod", GEOTIFF, RasterRole.elevation),
            Output(ERROR_MODEL),
        ),
        weight=0.1,
    ),
)


def comparison_pipeline(method: str | DetectionMethod) -> Pipeline[ComparisonContext]:
    """The stages of a comparison by `method`: the common ones, then its detection stage."""
    if not isinstance(method, DetectionMethod):
        method = detection_method(method)
    return Pipeline(f"comparison ({method.name})", (*COMMON_STAGES, method.stage))


def stages_for(method: str) -> tuple[str, ...]:
    """The stage names of a detection method, in order."""
    return comparison_pipeline(method).names


@dataclass
class ComparisonOptions:
    """Options of the common stages, the method, and the method's own options.

    `detection` is an instance of the method's `options_type` (its defaults when not
    given). In stored parameters (`to_dict`) it sits under the method's `options_key`
    ("vectorize", "score", "cnn"), as earlier versions stored it.
    """

    align: AlignOptions = field(default_factory=AlignOptions)
    coregister: CoregisterOptions = field(default_factory=CoregisterOptions)
    difference: DifferenceOptions = field(default_factory=DifferenceOptions)
    method: str = field(default_factory=default_method)
    detection: Any = None

    def __post_init__(self) -> None:
        options_type = detection_method(self.method).options_type
        if self.detection is None:
            self.detection = options_type()
        elif not isinstance(self.detection, options_type):
            raise InputError(
                f"the {self.method} method takes {options_type.__name__}, "
                f"not {type(self.detection).__name__}"
            )

    @property
    def detection_method(self) -> DetectionMethod:
        return detection_method(self.method)

    def to_dict(self) -> dict[str, Any]:
        return {
            "align": dataclasses.asdict(self.align),
            "coregister": dataclasses.asdict(self.coregister),
            "difference": dataclasses.asdict(self.difference),
            "method": self.method,
            self.detection_method.options_key: dataclasses.asdict(self.detection),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> ComparisonOptions:
        """Build from `to_dict()` output; missing keys take defaults, unknown keys fail.

        Parameters stored by earlier versions hold every method's options; those of other
        methods are accepted when they are that method's defaults (what was stored), and
        refused otherwise, since they would have no effect.
        """
        data = dict(data or {})
        method = detection_method(str(data.pop("method", default_method())))
        common = {"align": AlignOptions, "coregister": CoregisterOptions}
        common["difference"] = DifferenceOptions
        others = {m.options_key: m for m in detection_methods() if m.name != method.name}
        unknown = set(data) - set(common) - {method.options_key} - set(others)
        if unknown:
            raise InputError(f"unknown comparison options: {', '.join(sorted(unknown))}")
        kwargs: dict[str, Any] = {
            name: _options_from_dict(option_cls, name, data[name])
            for name, option_cls in common.items()
            if name in data
        }
        for key, other in others.items():
            if key in data and key != method.options_key:
                given = _options_from_dict(other.options_type, key, data[key])
                if given != other.options_type():
                    raise InputError(
                        f"{key} options belong to the {other.name} method, not {method.name}"
                    )
        if method.options_key in data:
            kwargs["detection"] = _options_from_dict(
                method.options_type, method.options_key, data[method.options_key]
            )
        return cls(method=method.name, **kwargs)


@dataclass
class ComparisonResult:
    results: dict[str, dict[str, Any]]  # stage name -> run_stage result
    work_dir: Path
    seconds: float

    @property
    def detections_path(self) -> Path:
        return self.work_dir / DETECTIONS

    def summary(self) -> dict[str, Any]:
        return summarize(self.results)


def compare_dsms(
    pre_path: Path,
    post_path: Path,
    work_dir: Path,
    options: ComparisonOptions | None = None,
    progress: ProgressFn = no_progress,
    from_stage: str | None = None,
) -> ComparisonResult:
    """Run the method's stages in order (from `from_stage`: the earlier ones must have run)."""
    options = options or ComparisonOptions()
    context = ComparisonContext(Path(pre_path), Path(post_path), Path(work_dir), options)
    run = comparison_pipeline(options.method).run(context, progress, from_stage)
    return ComparisonResult(results=run.results, work_dir=run.work_dir, seconds=run.seconds)


def run_stage(
    stage: str,
    pre_path: Path,
    post_path: Path,
    work_dir: Path,
    options: ComparisonOptions | Mapping[str, Any] | None = None,
    progress: ProgressFn = no_progress,
) -> dict[str, Any]:
    """Run one stage on the files of earlier stages in `work_dir`; return its result dict.

    The stage must belong to the method of `options` (see `stages_for`).
    """
    if not isinstance(options, ComparisonOptions):
        options = ComparisonOptions.from_dict(options)
    context = ComparisonContext(Path(pre_path), Path(post_path), Path(work_dir), options)
    return comparison_pipeline(options.method).run_stage(stage, context, progress)


def summarize(results: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """Short summary from stage results: detections, their total area, and the shift.

    shift_m is the correction applied to the post DSM, after its rotation by rotation_deg
    about the grid centre (see coregister.py).
    """
    detection_stages = [m.stage.name for m in detection_methods()]
    found = next((results[s] for s in detection_stages if results.get(s)), {})
    shift = results.get("coregister", {})
    return {
        "detections": int(found.get("detections", 0)),
        "total_area_m2": round(float(found.get("total_area_m2", 0.0)), 2),
        "shift_m": {
            "east": round(float(shift.get("shift_east_m", 0.0)), 4),
            "north": round(float(shift.get("shift_north_m", 0.0)), 4),
            "up": round(float(shift.get("shift_up_m", 0.0)), 4),
        },
        "rotation_deg": round(float(shift.get("rotation_deg", 0.0)), 4),
    }


def _options_from_dict(option_cls: type, name: str, values: Any) -> Any:
    if not isinstance(values, Mapping):
        raise InputError(f"comparison option {name!r} must be an object")
    known = {f.name for f in dataclasses.fields(option_cls)}
    unknown = set(values) - known
    if unknown:
        raise InputError(f"unknown {name} options: {', '.join(sorted(unknown))}")
    return option_cls(**values)
