"""The whole DSM comparison: align -> coregister -> difference -> vectorize | detect.

The stages depend on the detection method (`stages_for(method)`):

    threshold   align -> coregister -> difference -> vectorize  (the LoD method, the default)
    scored      align -> coregister -> difference -> score
    cnn         align -> coregister -> difference -> detect

`STAGES` is the threshold method's list (kept for callers that predate the cnn method).
`METHOD_SUMMARIES` says in one line what each method does (the API and the page show it).

Each stage reads only the caller's two DSMs or files that earlier stages wrote into
`work_dir`, and overwrites its own outputs atomically, so a stage can be re-run on its
own (one Celery task per stage). Layout of `work_dir`:

    pre_aligned.tif        align        pre DSM on the common metric grid (float32, -9999)
    post_aligned.tif       align        post DSM on the same grid
    post_coregistered.tif  coregister   post DSM corrected onto pre
    stable_mask.tif        coregister   uint8: 1 stable terrain, 0 excluded, 255 nodata
    dh.tif                 difference   post - pre in metres (float32, -9999)
    significance.tif       difference   uint8: 0 none, 1 loss, 2 gain, 255 nodata
    lod.tif                difference   per-pixel LoD95 in metres (float32, -9999)
    error_model.json       difference   sigma_dh(slope, curvature) and the variogram
    detections.geojson     vectorize    FeatureCollection, WGS84 lon/lat (threshold)
    detections.geojson     score        scored candidates, WGS84 lon/lat (scored)
    probability.tif        detect       per-pixel landslide probability, COG (cnn)
    cells.geojson          detect       positive 32-pixel cells, WGS84 (cnn)
    detections.geojson     detect       merged landslide polygons, WGS84 (cnn)

The cnn method's detect stage runs the detection model (worker/pipeline/cnn) on the
aligned pre DSM and the co-registered post DSM; its polygons carry the same properties
as the threshold method's, plus the model version (see cnn/detect_stage.py).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from worker.pipeline.align import AlignOptions, align
from worker.pipeline.cnn.options import CnnOptions
from worker.pipeline.coregister import CoregisterOptions, coregister
from worker.pipeline.difference import DifferenceOptions, difference
from worker.pipeline.errors import InputError, PipelineError
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.scoring import ScoreOptions, score_candidates
from worker.pipeline.vectorize import VectorizeOptions, vectorize

METHODS = ("threshold", "scored", "cnn")
METHOD_SUMMARIES = {
    "scored": "Significant change (per-pixel LoD and area tests), each candidate scored as a "
    "landslide probability by a calibrated model; trees and buildings set aside. Fewer false "
    "alarms than threshold, but it missed 2 of 36 slides that threshold found "
    "(docs/significance.md).",
    "threshold": "The LoD method: every change beyond its per-pixel level of detection "
    "(LoD95 from slope and curvature), larger than the errors' correlation.",
    "cnn": "SlideNet, a neural network on both DSMs, trained on simulated survey flights; on "
    "independent generators it found 1 of 36 slides (docs/significance.md).",
}
STAGES_BY_METHOD: dict[str, tuple[str, ...]] = {
    "scored": ("align", "coregister", "difference", "score"),
    "threshold": ("align", "coregister", "difference", "vectorize"),
    "cnn": ("align", "coregister", "difference", "detect"),
}
STAGES = STAGES_BY_METHOD["threshold"]
ALL_STAGES = ("align", "coregister", "difference", "vectorize", "score", "detect")
__all__ = [
    "ALL_STAGES",
    "METHODS",
    "METHOD_SUMMARIES",
    "STAGES",
    "STAGES_BY_METHOD",
    "ComparisonOptions",
    "ComparisonResult",
    "compare_dsms",
    "default_method",
    "run_stage",
    "stages_for",
    "summarize",
]

PRE_ALIGNED = "pre_aligned.tif"
POST_ALIGNED = "post_aligned.tif"
POST_COREGISTERED = "post_coregistered.tif"
STABLE_MASK = "stable_mask.tif"
DH = "dh.tif"
SIGNIFICANCE = "significance.tif"
DETECTIONS = "detections.geojson"
PROBABILITY = "probability.tif"
CELLS = "cells.geojson"

_INPUTS = {
    "align": (),
    "coregister": (PRE_ALIGNED, POST_ALIGNED),
    "difference": (PRE_ALIGNED, POST_COREGISTERED, STABLE_MASK),
    "vectorize": (DH, SIGNIFICANCE, PRE_ALIGNED, POST_COREGISTERED),
    "score": (DH, SIGNIFICANCE, PRE_ALIGNED, POST_COREGISTERED),
    "detect": (PRE_ALIGNED, POST_COREGISTERED, DH, SIGNIFICANCE),
}
# Share of the whole comparison's progress bar taken by each stage (from measured times).
_WEIGHTS = {
    "scored": {"align": 0.1, "coregister": 0.6, "difference": 0.15, "score": 0.15},
    "threshold": {"align": 0.1, "coregister": 0.75, "difference": 0.08, "vectorize": 0.07},
    "cnn": {"align": 0.1, "coregister": 0.6, "difference": 0.06, "detect": 0.24},
}


def stages_for(method: str) -> tuple[str, ...]:
    """The stage names of a detection method, in order."""
    try:
        return STAGES_BY_METHOD[method]
    except KeyError:
        raise InputError(
            f"unknown detection method {method!r}; available: {', '.join(METHODS)}"
        ) from None


def default_method() -> str:
    """The one default of the product: the CLI, the API and the page all use it.

    `threshold`, the LoD method with its per-pixel error model, because the default must
    never be worse than the simple baseline (one NMAD for the raster) on any benchmark
    set, and on the detection benchmark of 2026-11-25 (docs/significance.md) it was not:
    same or higher slide recall on every generator, fewer false alarms on most. `scored`
    cut false alarms further but missed two slides that the LoD method found, so it is
    chosen by name until it recovers them. ComparisonOptions itself also defaults to
    "threshold", so stored parameters keep their meaning.
    """
    return "threshold"


@dataclass
class ComparisonOptions:
    align: AlignOptions = field(default_factory=AlignOptions)
    coregister: CoregisterOptions = field(default_factory=CoregisterOptions)
    difference: DifferenceOptions = field(default_factory=DifferenceOptions)
    vectorize: VectorizeOptions = field(default_factory=VectorizeOptions)
    score: ScoreOptions = field(default_factory=ScoreOptions)
    cnn: CnnOptions = field(default_factory=CnnOptions)
    method: str = "threshold"

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> ComparisonOptions:
        """Build from `to_dict()` output; missing keys take defaults, unknown keys fail."""
        data = dict(data or {})
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise InputError(f"unknown comparison options: {', '.join(sorted(unknown))}")
        kwargs: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if f.name not in data:
                continue
            if f.name == "method":
                kwargs["method"] = str(data["method"])
                if kwargs["method"] not in METHODS:
                    raise InputError(
                        f"unknown detection method {kwargs['method']!r}; "
                        f"available: {', '.join(METHODS)}"
                    )
                continue
            option_cls = type(getattr(cls(), f.name))
            kwargs[f.name] = _options_from_dict(option_cls, f.name, data[f.name])
        return cls(**kwargs)


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
) -> ComparisonResult:
    """Run every stage of the method in order; outputs go to the layout in `work_dir`."""
    options = options or ComparisonOptions()
    start = time.perf_counter()
    results: dict[str, dict[str, Any]] = {}
    done = 0.0
    for stage in stages_for(options.method):
        weight = _WEIGHTS[options.method][stage]

        def stage_progress(fraction: float, done: float = done, weight: float = weight) -> None:
            progress(min(1.0, done + weight * fraction))

        results[stage] = run_stage(stage, pre_path, post_path, work_dir, options, stage_progress)
        done += weight
    progress(1.0)
    return ComparisonResult(
        results=results, work_dir=Path(work_dir), seconds=time.perf_counter() - start
    )


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
    if stage not in ALL_STAGES:
        raise ValueError(f"unknown stage {stage!r}; stages are {', '.join(ALL_STAGES)}")
    if not isinstance(options, ComparisonOptions):
        options = ComparisonOptions.from_dict(options)
    if stage not in stages_for(options.method):
        raise InputError(
            f"stage {stage!r} is not a stage of the {options.method} method; its stages "
            f"are {', '.join(stages_for(options.method))}"
        )
    work = Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    missing = [name for name in _INPUTS[stage] if not (work / name).exists()]
    if missing:
        raise PipelineError(
            f"stage {stage!r} needs {', '.join(missing)} in {work}; run the earlier stages first"
        )
    result: Any
    if stage == "align":
        result = align(
            Path(pre_path),
            Path(post_path),
            work / PRE_ALIGNED,
            work / POST_ALIGNED,
            options.align,
            progress,
        )
    elif stage == "coregister":
        result = coregister(
            work / PRE_ALIGNED,
            work / POST_ALIGNED,
            work / POST_COREGISTERED,
            options.coregister,
            progress,
            stable_mask_out=work / STABLE_MASK,
        )
    elif stage == "difference":
        result = difference(
            work / PRE_ALIGNED,
            work / POST_COREGISTERED,
            work / DH,
            work / SIGNIFICANCE,
            options.difference,
            stable_mask_path=work / STABLE_MASK,
            progress=progress,
        )
    elif stage == "detect":
        from worker.pipeline.cnn.detect_stage import detect_cnn  # torch only when needed

        result = detect_cnn(
            work / PRE_ALIGNED,
            work / POST_COREGISTERED,
            work / DH,
            work / SIGNIFICANCE,
            work / PROBABILITY,
            work / CELLS,
            work / DETECTIONS,
            options.cnn,
            progress,
        )
    elif stage == "score":
        result = score_candidates(
            work / DH,
            work / SIGNIFICANCE,
            work / PRE_ALIGNED,
            work / POST_COREGISTERED,
            work / DETECTIONS,
            options.score,
            progress,
            method=options.method,
        )
    else:
        result = vectorize(
            work / DH,
            work / SIGNIFICANCE,
            work / DETECTIONS,
            options.vectorize,
            options.method,
            progress,
            pre_path=work / PRE_ALIGNED,
            post_path=work / POST_COREGISTERED,
        )
    return result.to_dict()


def summarize(results: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """Short summary from stage results: detections, their total area, and the shift.

    shift_m is the correction applied to the post DSM (see coregister.py).
    """
    found = results.get("vectorize") or results.get("score") or results.get("detect") or {}
    shift = results.get("coregister", {})
    return {
        "detections": int(found.get("detections", 0)),
        "total_area_m2": round(float(found.get("total_area_m2", 0.0)), 2),
        "shift_m": {
            "east": round(float(shift.get("shift_east_m", 0.0)), 4),
            "north": round(float(shift.get("shift_north_m", 0.0)), 4),
            "up": round(float(shift.get("shift_up_m", 0.0)), 4),
        },
    }


def _options_from_dict(option_cls: type, name: str, values: Any) -> Any:
    if not isinstance(values, Mapping):
        raise InputError(f"comparison option {name!r} must be an object")
    known = {f.name for f in dataclasses.fields(option_cls)}
    unknown = set(values) - known
    if unknown:
        raise InputError(f"unknown {name} options: {', '.join(sorted(unknown))}")
    return option_cls(**values)
