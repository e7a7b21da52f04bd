"""The threshold method: every change beyond its per-pixel LoD95, as polygons (the default)."""

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
from worker.pipeline.progress import ProgressFn
from worker.pipeline.stages import StageSpec
from worker.pipeline.vectorize import VectorizeOptions, VectorizeResult, vectorize


def run_vectorize(context: ComparisonContext, progress: ProgressFn) -> VectorizeResult:
    return vectorize(
        context.file(DH),
        context.file(SIGNIFICANCE),
        context.file(DETECTIONS),
        context.detection,
        context.options.method,
        progress,
        pre_path=context.file(PRE_ALIGNED),
        post_path=context.file(POST_COREGISTERED),
    )


# The simple baseline the default is measured against (benchmarks and the paper's
# protocol): one NMAD for the whole raster and no volume test; the comparison options
# that turn this method into it.
BASELINE_OPTIONS = {"difference": {"error_model": "uniform"}, "vectorize": {"min_volume_z": None}}

METHOD = DetectionMethod(
    name="threshold",
    summary="The LoD method: every change beyond its per-pixel level of detection "
    "(LoD95 from slope and curvature, never below the raster's one-NMAD LoD; edges drawn out "
    "to that LoD), larger than the errors' correlation or, if smaller, twice its LoD, and "
    "with a loss or gain volume 3 standard errors clear of zero; trees and buildings that "
    "changed on unmoved ground are set aside.",
    stage=StageSpec(
        name="vectorize",
        run=run_vectorize,
        help="significant change into polygons",
        inputs=DETECTION_INPUTS,
        outputs=(DETECTIONS_OUTPUT,),
        weight=0.07,
    ),
    options_type=VectorizeOptions,
    options_key="vectorize",
)
