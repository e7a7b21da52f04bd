"""Elevation difference, its noise level on stable terrain, and significant change.

dh = post - pre (metres, float32, nodata -9999). The level of detection is
LoD95 = 1.96 * NMAD(dh on stable terrain), floored at `min_lod_m`, unless the user fixes
`lod_m`. The significance mask (uint8) holds 0 no significant change, 1 loss
(dh < -LoD), 2 gain (dh > +LoD), 255 nodata.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from worker.pipeline.errors import InputError
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.raster_io import MASK_NODATA, read_elevation, write_geotiff

NO_CHANGE, LOSS, GAIN = 0, 1, 2
LOD_Z = 1.96  # two-sided 95 % for a normal error


@dataclass
class DifferenceOptions:
    min_lod_m: float = 0.1  # floor: stable-terrain NMAD can understate real survey noise
    lod_m: float | None = None  # fixed threshold; overrides the computed LoD95
    outlier_nmad_factor: float = 4.0  # without a stable mask: exclusion of change pixels
    min_stable_pixels: int = 1_000


@dataclass
class DifferenceResult:
    nmad_m: float
    lod95_m: float  # 1.96 * NMAD
    lod_m: float  # the threshold applied (LoD95, floored, or the fixed lod_m)
    median_dh_m: float  # on stable terrain
    stable_pixels: int
    significant_loss_pixels: int
    significant_gain_pixels: int
    pixel_area_m2: float
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def difference(
    pre_path: Path,
    post_path: Path,
    dh_out: Path,
    significance_out: Path,
    options: DifferenceOptions | None = None,
    stable_mask_path: Path | None = None,
    progress: ProgressFn = no_progress,
) -> DifferenceResult:
    """Write dh and its significance mask; both inputs must be on the same grid.

    `stable_mask_path` is the co-registration's mask (1 = stable); without it, stable
    terrain is every valid pixel within `outlier_nmad_factor` NMAD of the median.
    """
    options = options or DifferenceOptions()
    start = time.perf_counter()
    pre, profile = read_elevation(pre_path)
    post, post_profile = read_elevation(post_path)
    if pre.shape != post.shape or post_profile["transform"] != profile["transform"]:
        raise InputError("pre and post DSMs must be on the same grid: run the align stage first")
    dh = post - pre
    valid = np.isfinite(dh)
    if not valid.any():
        raise InputError("the pre and post DSMs have no valid elevations in common")
    progress(0.3)

    stable = _stable_pixels(dh, valid, stable_mask_path, options)
    stable_values = dh[stable]
    median = float(np.median(stable_values))
    nmad = float(1.4826 * np.median(np.abs(stable_values - median)))
    lod95 = LOD_Z * nmad
    lod = options.lod_m if options.lod_m is not None else max(lod95, options.min_lod_m)
    if not lod > 0:
        raise InputError("the level of detection must be a positive number of metres")

    significance = np.full(dh.shape, MASK_NODATA, dtype=np.uint8)
    significance[valid] = NO_CHANGE
    with np.errstate(invalid="ignore"):
        significance[valid & (dh < -lod)] = LOSS
        significance[valid & (dh > lod)] = GAIN
    progress(0.6)
    transform, crs = profile["transform"], profile["crs"]
    write_geotiff(dh_out, dh, transform, crs)
    write_geotiff(significance_out, significance, transform, crs, tags={"LOD_M": repr(lod)})
    progress(1.0)
    return DifferenceResult(
        nmad_m=nmad,
        lod95_m=lod95,
        lod_m=float(lod),
        median_dh_m=median,
        stable_pixels=int(stable_values.size),
        significant_loss_pixels=int(np.count_nonzero(significance == LOSS)),
        significant_gain_pixels=int(np.count_nonzero(significance == GAIN)),
        pixel_area_m2=float(abs(transform.a * transform.e)),
        seconds=time.perf_counter() - start,
    )


def _stable_pixels(
    dh: np.ndarray, valid: np.ndarray, stable_mask_path: Path | None, options: DifferenceOptions
) -> np.ndarray:
    if stable_mask_path is not None:
        mask, _ = read_elevation(stable_mask_path)
        if mask.shape != dh.shape:
            raise InputError("the stable-terrain mask is not on the grid of the DSMs")
        stable = valid & (mask == 1)
        if np.count_nonzero(stable) >= options.min_stable_pixels:
            return stable
    values = dh[valid]
    median = np.median(values)
    nmad = 1.4826 * np.median(np.abs(values - median))
    with np.errstate(invalid="ignore"):
        stable = valid & (np.abs(dh - median) <= options.outlier_nmad_factor * nmad)
    if np.count_nonzero(stable) < min(options.min_stable_pixels, np.count_nonzero(valid)):
        return valid
    return stable
