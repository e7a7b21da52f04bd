"""A toy detection method, declared and registered the way any new method is.

One module plus one registration (here at import, named in the setting
SLIDEWATCH_DETECTION_METHOD_MODULES): the CLI, the API's method list and the comparison job all
see it. It reports one detection: the bounding box of the pixels whose |Δh| exceeds a
fixed height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from shapely.geometry import box

from worker.pipeline.comparison_layout import (
    DETECTIONS,
    DETECTIONS_OUTPUT,
    DH,
    ComparisonContext,
    DetectionMethod,
)
from worker.pipeline.detection_methods import register_method
from worker.pipeline.detection_record import DetectionProperties, write_detections
from worker.pipeline.geo import to_wgs84_geojson
from worker.pipeline.progress import ProgressFn
from worker.pipeline.raster_io import read_elevation
from worker.pipeline.stages import StageSpec


@dataclass
class ToyOptions:
    height_m: float = 1.0


def run_toy(context: ComparisonContext, progress: ProgressFn) -> dict[str, float]:
    dh, profile = read_elevation(context.file(DH))
    changed = np.abs(np.nan_to_num(dh)) > context.detection.height_m
    detections = []
    if changed.any():
        rows, cols = np.nonzero(changed)
        transform = profile["transform"]
        x0, y0 = transform * (cols.min(), rows.max() + 1)
        x1, y1 = transform * (cols.max() + 1, rows.min())
        geometry = box(x0, y0, x1, y1)
        properties = DetectionProperties(
            area_m2=round(geometry.area, 2),
            volume_loss_m3=0.0,
            volume_gain_m3=0.0,
            max_abs_dh_m=round(float(np.nanmax(np.abs(dh))), 3),
            score=1.0,
            method="toy",
        )
        detections.append((to_wgs84_geojson(geometry, profile["crs"]), properties))
    write_detections(context.file(DETECTIONS), detections, profile["crs"])
    progress(1.0)
    return {"detections": len(detections), "total_area_m2": sum(p.area_m2 for _, p in detections)}


METHOD = register_method(
    DetectionMethod(
        name="toy",
        summary="A toy: the bounding box of every change above a fixed height.",
        stage=StageSpec(
            name="box",
            run=run_toy,
            help="change above a height, boxed",
            inputs=(DH,),
            outputs=(DETECTIONS_OUTPUT,),
        ),
        options_type=ToyOptions,
        options_key="toy",
    )
)
