"""Bring the pre and post DSMs onto one metric grid over their common footprint.

Grid rules:
- CRS: the pre DSM's CRS when it is projected in metres, else the UTM zone of the
  overlap's centroid (see geo.py for the zone rule).
- Resolution: the coarser of the two DSMs (largest pixel side, in metres), unless
  `AlignOptions.resolution_m` is set.
- Extent: the intersection of both footprints' bounding boxes in that CRS, shrunk to
  whole multiples of the resolution (so grids of repeated runs line up).
- Values: bilinear resampling; a pixel is valid only if every source pixel it draws from
  is valid. Outputs are float32 GeoTIFFs with nodata -9999.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.warp
from rasterio.transform import from_origin
from shapely.geometry import shape as to_shape

from worker.pipeline.dsm_inspect import DsmInfo, inspect_dsm
from worker.pipeline.errors import InputError
from worker.pipeline.geo import crs_to_string, is_metric_projected, utm_epsg_for_lonlat
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.raster_io import read_elevation, warp_elevation, write_geotiff
from worker.pipeline.stages import StageResult


@dataclass
class AlignOptions:
    resolution_m: float | None = None  # None: the coarser of the two DSMs
    min_overlap_pixels: int = 10_000  # valid in both DSMs, on the common grid


@dataclass
class AlignResult(StageResult):
    crs: str
    shape: tuple[int, int]  # rows, cols
    resolution_m: float
    bounds: tuple[float, float, float, float]  # left, bottom, right, top in `crs`
    overlap_area_m2: float  # area of the common grid
    valid_overlap_area_m2: float  # where both DSMs have elevations
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["shape"] = list(self.shape)
        data["bounds"] = list(self.bounds)
        return data


def align(
    pre_path: Path,
    post_path: Path,
    pre_out: Path,
    post_out: Path,
    options: AlignOptions | None = None,
    progress: ProgressFn = no_progress,
) -> AlignResult:
    """Resample both DSMs onto the common grid and write them to `pre_out` and `post_out`."""
    options = options or AlignOptions()
    start = time.perf_counter()
    pre_info, post_info = inspect_dsm(pre_path), inspect_dsm(post_path)
    progress(0.1)
    with rasterio.open(pre_path) as pre_src, rasterio.open(post_path) as post_src:
        pre_crs, post_crs = pre_src.crs, post_src.crs
    target_crs = _target_crs(pre_crs, pre_info, post_info)
    # Automatic resolutions are rounded to the millimetre so that lon/lat inputs give tidy grids.
    resolution = options.resolution_m or round(
        max(*pre_info.resolution_m, *post_info.resolution_m), 3
    )
    if not resolution > 0:
        raise InputError("the grid resolution must be a positive number of metres")

    bounds = _common_bounds(pre_info, pre_crs, post_info, post_crs, target_crs, resolution)
    left, bottom, right, top = bounds
    shape = (round((top - bottom) / resolution), round((right - left) / resolution))
    transform = from_origin(left, top, resolution, resolution)

    arrays = []
    for i, (path, label) in enumerate(((pre_path, "pre"), (post_path, "post"))):
        source, profile = read_elevation(path)
        warped = warp_elevation(
            source, profile["transform"], profile["crs"], transform, target_crs, shape
        )
        if not np.isfinite(warped).any():
            raise InputError(
                f"the {label} DSM has no valid elevations where it overlaps the other DSM"
            )
        arrays.append(warped)
        progress(0.1 + 0.35 * (i + 1))
    valid_both = int(np.count_nonzero(np.isfinite(arrays[0]) & np.isfinite(arrays[1])))
    if valid_both < options.min_overlap_pixels:
        raise InputError(
            f"the overlap of the pre and post DSMs is too small: {valid_both} pixels with "
            f"elevations in both at {resolution:g} m, at least {options.min_overlap_pixels} needed"
        )

    write_geotiff(pre_out, arrays[0], transform, target_crs)
    write_geotiff(post_out, arrays[1], transform, target_crs)
    progress(1.0)
    return AlignResult(
        crs=crs_to_string(target_crs),
        shape=shape,
        resolution_m=float(resolution),
        bounds=(left, bottom, right, top),
        overlap_area_m2=float(shape[0] * shape[1] * resolution**2),
        valid_overlap_area_m2=float(valid_both * resolution**2),
        seconds=time.perf_counter() - start,
    )


def _target_crs(
    pre_crs: rasterio.crs.CRS, pre_info: DsmInfo, post_info: DsmInfo
) -> rasterio.crs.CRS:
    if is_metric_projected(pre_crs):
        return pre_crs
    lon, lat = _overlap_centroid_lonlat(pre_info, post_info)
    return rasterio.crs.CRS.from_epsg(utm_epsg_for_lonlat(lon, lat))


def _overlap_centroid_lonlat(pre_info: DsmInfo, post_info: DsmInfo) -> tuple[float, float]:
    overlap = to_shape(pre_info.footprint).intersection(to_shape(post_info.footprint))
    if overlap.is_empty:
        raise InputError("pre and post DSMs do not overlap")
    centroid = overlap.centroid
    return centroid.x, centroid.y


def _common_bounds(
    pre_info: DsmInfo,
    pre_crs: rasterio.crs.CRS,
    post_info: DsmInfo,
    post_crs: rasterio.crs.CRS,
    target_crs: rasterio.crs.CRS,
    resolution: float,
) -> tuple[float, float, float, float]:
    boxes = [
        rasterio.warp.transform_bounds(crs, target_crs, *info.bounds, densify_pts=21)
        for info, crs in ((pre_info, pre_crs), (post_info, post_crs))
    ]
    left = max(boxes[0][0], boxes[1][0])
    bottom = max(boxes[0][1], boxes[1][1])
    right = min(boxes[0][2], boxes[1][2])
    top = min(boxes[0][3], boxes[1][3])
    if left >= right or bottom >= top:
        raise InputError("pre and post DSMs do not overlap")
    # Shrink inwards to multiples of the resolution; the small epsilon keeps an edge that
    # is already on a multiple from moving by a whole pixel through rounding noise.
    eps = 1e-6 * resolution
    left = math.ceil(left / resolution - eps) * resolution
    bottom = math.ceil(bottom / resolution - eps) * resolution
    right = math.floor(right / resolution + eps) * resolution
    top = math.floor(top / resolution + eps) * resolution
    if left >= right or bottom >= top:
        raise InputError("pre and post DSMs do not overlap by even one pixel")
    return left, bottom, right, top
