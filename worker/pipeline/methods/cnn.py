"""The cnn method: SlideNet, a neural network on both DSMs (worker/pipeline/cnn)."""

from __future__ import annotations

from typing import Any

from worker.pipeline.cnn.options import CnnOptions
from worker.pipeline.cog import RasterRole
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
from worker.pipeline.stages import GEOJSON, GEOTIFF, Output, StageSpec

PROBABILITY = "probability.tif"
CELLS = "cells.geojson"


def run_detect(context: ComparisonContext, progress: ProgressFn) -> Any:
    # torch is imported only by comparisons that run the network.
    from worker.pipeline.cnn.detect_stage import detect_cnn

    return detect_cnn(
        context.file(PRE_ALIGNED),
        context.file(POST_COREGISTERED),
        context.file(DH),
        context.file(SIGNIFICANCE),
        context.file(PROBABILITY),
        context.file(CELLS),
        context.file(DETECTIONS),
        context.detection,
        progress,
    )


METHOD = DetectionMethod(
    name="cnn",
    summary="SlideNet, a neural network on both DSMs, trained on simulated survey flights; on "
    "independent generators it found 1 of 45 slides (docs/significance.md).",
    stage=StageSpec(
        name="detect",
        run=run_detect,
        help="detection model on the DSMs",
        inputs=DETECTION_INPUTS,
        outputs=(
            # A probability 0-1 is continuous: overviews average it, as elevations.
            Output(PROBABILITY, "probability", GEOTIFF, RasterRole.elevation),
            Output(CELLS, "cells", GEOJSON),
            DETECTIONS_OUTPUT,
        ),
        weight=0.24,
    ),
    options_type=CnnOptions,
    options_key="cnn",
    needs_model=True,
)
