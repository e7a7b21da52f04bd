"""The scored method: significant-change candidates scored as landslide probabilities."""

from __future__ import annotations

from worker.pipeline.comparison_layout import (
    DETECTION_INPUTS,
    DETECTIONS,
    DETECTIONS_OUTPUT,
    DH,
    POST_COREGISTERED,
    PRE_ALIGNED,
    SIGNIFICANCE,
    ComparisonContext,
    DetectionMethod,
)
from worker.pipeline.errors import InputError
from worker.pipeline.progress import ProgressFn
from worker.pipeline.scorer import shipped_scorer_available
from worker.pipeline.scoring import ScoreOptions, ScoreResult, score_candidates
from worker.pipeline.stages import StageSpec


def run_score(context: ComparisonContext, progress: ProgressFn) -> ScoreResult:
    return score_candidates(
        context.file(DH),
        context.file(SIGNIFICANCE),
        context.file(PRE_ALIGNED),
        context.file(POST_COREGISTERED),
        context.file(DETECTIONS),
        context.detection,
        progress,
        method=context.options.method,
    )


def check_request(options: ScoreOptions) -> None:
    """A comparison over the API runs the scorer that ships with the installation only.

    A scorer path from an API user would be a file on the server opened by the worker;
    as with detection models, only what the installation provides runs.
    """
    if options.scorer is not None:
        raise InputError(
            "the scored method runs the scorer shipped with slidewatch; "
            "parameters.score.scorer cannot be set over the API"
        )
    if not shipped_scorer_available():
        raise InputError("the scorer of the scored method is not installed: use method threshold")


METHOD = DetectionMethod(
    name="scored",
    summary="Significant change (per-pixel LoD and area tests), each candidate scored as a "
    "landslide probability by a calibrated model; trees and buildings set aside. Fewer false "
    "alarms than threshold, but it found 36 of 45 deep slides where threshold found 41 "
    "(docs/significance.md).",
    stage=StageSpec(
        name="score",
        run=run_score,
        help="change candidates scored as landslides",
        inputs=DETECTION_INPUTS,
        outputs=(DETECTIONS_OUTPUT,),
        weight=0.15,
    ),
    options_type=ScoreOptions,
    options_key="score",
    check_request=check_request,
)
