"""Turn significant change into landslide polygons (GeoJSON, RFC 7946): the LoD method.

The significant pixels of the difference stage (beyond their per-pixel LoD95), loss and
gain together since a landslide is depletion and deposition side by side, are cleaned
(an opening removes speckle, a closing bridges gaps) and grouped 8-connected; regions
smaller than the minimum area (from the errors' correlation length unless fixed, see
change_regions.RegionOptions) are dropped, and so are regions whose loss and gain
volumes are both within `min_volume_z` standard errors of zero under the fitted
variogram (a patch of correlated error that passed the pixel LoD). Regions that are
tall objects appearing or vanishing with no ground motion around them (trees, buildings),
or, with `vegetation_cut`, low vegetation cut (grass mown: vegetation_cut.py), are set
aside as surface changes and counted, not reported as landslides. Polygons
follow pixel edges in the metric CRS, where areas are measured, and are written in WGS84
lon/lat with their 95 % intervals (change_regions.py).

score (0-1) is a confidence: magnitude * size, where magnitude = 1 - exp(-(m - 1)) with
m the region's mean |dh| in multiples of its LoD (0 at the LoD, 0.86 at 3 LoD), and
size = 1 - exp(-area / (2 * minimum area)) (0.39 at the minimum area, 0.86 at 4 times).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from worker.pipeline.change_regions import (
    OBJECTS,
    VEGETATION_CUT,
    Region,
    RegionOptions,
    describe_region,
    grow_into_baseline,
    judge_by_baseline,
    label_regions,
    load_change_rasters,
    min_area_m2,
    region_detection,
    significant_regions,
    split_surface_changes,
)
from worker.pipeline.detection_record import write_detections
from worker.pipeline.errors import InputError
from worker.pipeline.geo import crs_to_string
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.stages import StageResult

METHODS = ("threshold",)


@dataclass
class VectorizeOptions(RegionOptions):
    # A landslide region's loss or gain volume must reach this many standard errors of
    # that volume (its errors correlated as the variogram says): a patch of correlated
    # error that passed the pixel LoD is about one correlation area of pixels just past
    # it, 1.5-3 standard errors as a volume. 3: the largest value that lost no slide on
    # the training seeds 0-11 of the seven pair generators (docs/significance.md), where
    # 3.25 lost one and 4 three. None: no volume test.
    min_volume_z: float | None = 3.0
    # Judge surface change on the simple baseline's region around each region too
    # (change_regions.judge_by_baseline): the default then sets aside whatever the
    # baseline does.
    surface_by_baseline: bool = True
    # Measure the context rule (objects lost near a landslide join it) from the simple
    # baseline's region around each region too (judge_by_baseline): the default then
    # joins whatever the baseline does.
    context_by_baseline: bool = True
    # Each region kept is grown, one pixel at a time up to this many, into neighbouring
    # pixels of the simple baseline's regions (change_regions.grow_into_baseline): the
    # per-pixel LoD finds the change, the baseline's draws its edge. 6: on the paper's
    # protocol (fitted there) the default then finds every patch the baseline finds on
    # all four patterns, where 3 left one short on each and 0 two. 0: not grown.
    baseline_fringe_px: int = 6


@dataclass
class VectorizeResult(StageResult):
    detections: int
    total_area_m2: float
    total_volume_loss_m3: float
    total_volume_gain_m3: float
    # Regions set aside as surface change: trees or buildings appearing or vanishing,
    # and low vegetation cut (of which `vegetation_cuts`).
    surface_changes: int
    surface_change_area_m2: float
    vegetation_cuts: int
    vegetation_cut_area_m2: float
    min_area_m2: float
    method: str
    crs: str  # the metric CRS where areas and volumes were measured
    seconds: float


def vectorize(
    dh_path: Path,
    significance_path: Path,
    out_geojson: Path,
    options: VectorizeOptions | None = None,
    method: str = "threshold",
    progress: ProgressFn = no_progress,
    pre_path: Path | None = None,
    post_path: Path | None = None,
) -> VectorizeResult:
    """Write the detections as a FeatureCollection to `out_geojson` (atomically).

    With `pre_path` and `post_path` (the aligned and co-registered DSMs), trees and
    buildings that appeared or vanished are told apart from landslides.
    """
    options = options or VectorizeOptions()
    if method not in METHODS:
        raise InputError(f"unknown detection method {method!r}; available: {', '.join(METHODS)}")
    start = time.perf_counter()
    rasters = load_change_rasters(dh_path, significance_path, pre_path, post_path)
    smallest = min_area_m2(rasters, options)
    labels, keep, windows = label_regions(significant_regions(rasters, options), rasters, options)
    if options.baseline_fringe_px > 0:
        labels, windows = grow_into_baseline(
            labels, keep, rasters, options.baseline_fringe_px, options
        )
    progress(0.4)
    regions = [
        describe_region(rasters, labels, label, window, options)
        for label, window in zip(keep, windows, strict=True)
    ]
    if options.surface_by_baseline or options.context_by_baseline:
        regions = judge_by_baseline(
            rasters,
            labels,
            keep,
            windows,
            regions,
            options,
            set_aside=options.surface_by_baseline,
            context=options.context_by_baseline,
        )
    landslides, surface = split_surface_changes(
        [r for r in regions if _volume_significant(r, options)], options
    )
    progress(0.9)
    detections = [region_detection(r, rasters.crs, _score(r, smallest), method) for r in landslides]
    collection = write_detections(out_geojson, detections, rasters.crs)
    progress(1.0)
    return VectorizeResult(
        **detection_totals(collection, surface),
        min_area_m2=round(smallest, 3),
        method=method,
        crs=crs_to_string(rasters.crs),
        seconds=time.perf_counter() - start,
    )


def detection_totals(collection: dict[str, Any], surface: list[Region]) -> dict[str, Any]:
    """The result fields that sum the written detections and the set-aside surface changes."""
    props = [f["properties"] for f in collection["features"]]
    cuts = [r for r in surface if r.cause == VEGETATION_CUT]
    return {
        "detections": len(props),
        "total_area_m2": float(sum(p["area_m2"] for p in props)),
        "total_volume_loss_m3": float(sum(p["volume_loss_m3"] for p in props)),
        "total_volume_gain_m3": float(sum(p["volume_gain_m3"] for p in props)),
        "surface_changes": len(surface),
        "surface_change_area_m2": round(float(sum(r.geometry.area for r in surface)), 2),
        "vegetation_cuts": len(cuts),
        "vegetation_cut_area_m2": round(float(sum(r.geometry.area for r in cuts)), 2),
    }


def _volume_significant(region: Region, options: VectorizeOptions) -> bool:
    """Tall objects that appeared or vanished are judged by the object rule; landslides
    and vegetation cuts (which join a landslide beside their deposit) by their volume
    too."""
    if region.cause == OBJECTS or options.min_volume_z is None:
        return True
    return region.traits["volume_z"] >= options.min_volume_z


def _score(region: Region, smallest_m2: float) -> float:
    m = region.traits["mean_lod_ratio"]
    magnitude = max(0.0, min(1.0, 1.0 - math.exp(-(m - 1.0))))
    size = 1.0 - math.exp(-region.properties["area_m2"] / (2.0 * max(smallest_m2, 1e-9)))
    return magnitude * size
