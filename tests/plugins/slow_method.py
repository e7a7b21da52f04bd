"""A detection method whose one stage is busy for a set time: a stage to kill mid-run.

Registered like any method (named in SLIDEWATCH_DETECTION_METHOD_MODULES). Its stage
`linger` works in a temporary folder beside its outputs, as the CNN detection stage does,
so that a killed attempt leaves one behind; it then waits `seconds` (reporting progress)
and writes no detection. Deterministic and cheap, unlike a real stage made slow by a
large input.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from worker.pipeline.comparison_layout import (
    DETECTIONS,
    DETECTIONS_OUTPUT,
    DH,
    ComparisonContext,
    DetectionMethod,
)
from worker.pipeline.detection_methods import register_method
from worker.pipeline.detection_record import write_detections
from worker.pipeline.progress import ProgressFn
from worker.pipeline.raster_io import read_elevation
from worker.pipeline.stages import StageSpec


@dataclass
class LingerOptions:
    seconds: float = 0.0


def run_linger(context: ComparisonContext, progress: ProgressFn) -> dict[str, float]:
    _dh, profile = read_elevation(context.file(DH))
    seconds = float(context.detection.seconds)
    with tempfile.TemporaryDirectory(dir=Path(context.work_dir)) as scratch:
        (Path(scratch) / "started").write_text("a killed attempt leaves this folder behind")
        started = time.monotonic()
        while (elapsed := time.monotonic() - started) < seconds:
            progress(elapsed / seconds)
            time.sleep(0.05)
    write_detections(context.file(DETECTIONS), [], profile["crs"])
    progress(1.0)
    return {"detections": 0, "lingered_s": seconds}


METHOD = register_method(
    DetectionMethod(
        name="linger",
        summary="A test method: busy for a set time, then no detection.",
        stage=StageSpec(
            name="linger",
            run=run_linger,
            help="wait, for tests that kill a busy stage",
            inputs=(DH,),
            outputs=(DETECTIONS_OUTPUT,),
        ),
        options_type=LingerOptions,
        options_key="linger",
    )
)
