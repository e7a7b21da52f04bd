"""Elevation difference, its error model, and significant change per pixel.

dh = post - pre (metres, float32, nodata -9999). The error of dh is learned from the
difference itself on stable terrain (error_model.py): sigma_dh per pixel from slope and
curvature, and the correlation of the errors. The level of detection is per pixel,
LoD95 = 1.96 * sigma_dh, floored at `min_lod_m`; `error_model="uniform"` gives the simple
baseline, one sigma (the NMAD of stable terrain) for the whole raster; a fixed `lod_m`
overrides both. By default (`uniform_floor`) the per-pixel LoD is also floored at the
baseline's and a pixel must pass the baseline's test as well, so the default never marks
a pixel the baseline would not; pixels past the baseline's LoD whose neighbourhood is
significant as an area join the change they touch (`flank_area_z`; docs/significance.md,
"The baseline as a floor, and the flanks of change"). The significance mask (uint8)
holds 0 no significant change, 1 loss (dh < -LoD), 2 gain (dh > +LoD), 255 nodata.

Outputs: `dh_out`, `significance_out` (its LOD_M tag is the median LoD), and beside them
`lod.tif` (per-pixel LoD95, float32) and `error_model.json` (the fitted model, which the
later stages use for minimum areas and the 95 % intervals of areas and volumes).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.error_model import (
    LOD_Z,
    ErrorModel,
    ErrorModelOptions,
    area_t,
    fit_error_model,
    terrain_attributes,
)
from worker.pipeline.errors import InputError
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.raster_io import MASK_NODATA, read_elevation, write_geotiff
from worker.pipeline.stages import StageResult

NO_CHANGE, LOSS, GAIN = 0, 1, 2
ERROR_MODELS = ("heteroscedastic", "uniform")
LOD_FILE = "lod.tif"
ERROR_MODEL_FILE = "error_model.json"
# Tags of the significance mask: the simple baseline's median, LoD95 and correlation
# length (floored only).
BASELINE_MEDIAN_TAG = "BASELINE_MEDIAN_M"
BASELINE_LOD_TAG = "BASELINE_LOD_M"
BASELINE_CORRELATION_TAG = "BASELINE_CORRELATION_LENGTH_M"
__all__ = ["GAIN", "LOD_Z", "LOSS", "NO_CHANGE", "DifferenceOptions", "difference"]


@dataclass
class DifferenceOptions:
    error_model: str = "heteroscedastic"  # or "uniform": one NMAD for the whole raster
    min_lod_m: float = 0.0  # floor of the per-pixel LoD
    lod_m: float | None = None  # fixed threshold; overrides the error model's LoD
    outlier_nmad_factor: float = 4.0  # uniform model: exclusion of change pixels
    min_stable_pixels: int = 1_000
    attribute_scale_m: float = 0.1  # slope and curvature measured at this scale
    # The per-pixel model is fitted again without regions whose |dh| averages this many
    # LoDs (see ErrorModelOptions); None: fitted once. The uniform baseline ignores it.
    strong_change_lod_ratio: float | None = ErrorModelOptions.strong_change_lod_ratio
    # The per-pixel LoD is never below the raster's one-NMAD LoD95, and a pixel must pass
    # that test too (about the baseline's own median): the default never marks change the
    # simple baseline does not, and keeps the error model's higher LoD on rough ground.
    uniform_floor: bool = True
    # With the floor: pixels beyond the baseline's LoD (same sign) whose neighbourhood is
    # significant as an area under the error model (mean z beyond this many standard
    # errors, as the scored method's area candidates) join the significant change they
    # touch: the flanks of a change on steep ground, under the per-pixel LoD there but
    # coherent with it. None: the floored pixel test alone.
    flank_area_z: float | None = 4.0


@dataclass
class DifferenceResult(StageResult):
    nmad_m: float  # of stable terrain, one number (the uniform model's sigma)
    lod95_m: float  # 1.96 * NMAD: the uniform model's LoD
    lod_m: float  # the median per-pixel LoD applied (the fixed lod_m when given)
    lod_p10_m: float
    lod_p90_m: float
    error_model: str  # heteroscedastic, uniform or fixed
    correlation_length_m: float
    # The simple baseline's, which the default's minimum area is never below; None where
    # the LoD is not floored at the baseline's.
    baseline_correlation_length_m: float | None
    sigma_by_slope: list[list[float]]  # [slope_deg, sigma_m] on the least curved ground
    median_dh_m: float  # on stable terrain
    stable_pixels: int
    significant_loss_pixels: int
    significant_gain_pixels: int
    pixel_area_m2: float
    seconds: float


def difference(
    pre_path: Path,
    post_path: Path,
    dh_out: Path,
    significance_out: Path,
    options: DifferenceOptions | None = None,
    stable_mask_path: Path | None = None,
    progress: ProgressFn = no_progress,
) -> DifferenceResult:
    """Write dh, its significance mask, the per-pixel LoD and the error model.

    Both inputs must be on the same grid. `stable_mask_path` (the co-registration's
    mask, 1 = stable) only limits where stable terrain is looked for in the uniform
    model; the heteroscedastic model finds its own (see error_model.py).
    """
    options = options or DifferenceOptions()
    if options.error_model not in ERROR_MODELS:
        raise InputError(
            f"unknown error model {options.error_model!r}; available: {', '.join(ERROR_MODELS)}"
        )
    start = time.perf_counter()
    pre, profile = read_elevation(pre_path)
    post, post_profile = read_elevation(post_path)
    if pre.shape != post.shape or post_profile["transform"] != profile["transform"]:
        raise InputError("pre and post DSMs must be on the same grid: run the align stage first")
    dh = post - pre
    valid = np.isfinite(dh)
    if not valid.any():
        raise InputError("the pre and post DSMs have no valid elevations in common")
    transform, crs = profile["transform"], profile["crs"]
    pixel_size = float(abs(transform.a))
    progress(0.1)

    stable = _stable_pixels(dh, valid, stable_mask_path, options)
    stable_values = dh[stable]
    median = float(np.median(stable_values))
    nmad = float(1.4826 * np.median(np.abs(stable_values - median)))
    lod95 = LOD_Z * nmad

    # Slope and curvature of the mean surface: both surveys see the same ground.
    mean_surface = np.where(np.isfinite(pre), pre, post)
    both = valid
    mean_surface[both] = 0.5 * (pre[both] + post[both])
    slope, curvature = terrain_attributes(mean_surface, pixel_size, options.attribute_scale_m)
    del mean_surface
    progress(0.3)
    floored = (
        options.uniform_floor and options.error_model == "heteroscedastic" and options.lod_m is None
    )
    model, sigma, baseline_length = _error_model(
        dh, slope, curvature, pixel_size, stable, median, nmad, options, floored
    )
    progress(0.7)
    if options.lod_m is not None:
        if not options.lod_m > 0:
            raise InputError("the level of detection must be a positive number of metres")
        lod = np.where(valid, np.float32(options.lod_m), np.nan).astype(np.float32)
        kind = "fixed"
    else:
        floor = max(options.min_lod_m, lod95 if floored else 0.0)
        lod = np.maximum(sigma * np.float32(LOD_Z), np.float32(floor))
        lod[~valid] = np.nan
        kind = options.error_model
    del slope, curvature
    centred = dh - np.float32(model.median_dh_m if options.lod_m is None else 0.0)
    significance = np.full(dh.shape, MASK_NODATA, dtype=np.uint8)
    significance[valid] = NO_CHANGE
    with np.errstate(invalid="ignore"):
        loss = valid & (centred < -lod)
        gain = valid & (centred > lod)
        if floored:
            baseline = dh - np.float32(median)
            loss &= baseline < -np.float32(lod95)
            gain &= baseline > np.float32(lod95)
            if options.flank_area_z is not None:
                _, t, weight = area_t(centred / sigma, model, pixel_size)
                for change, sign in ((loss, -1.0), (gain, 1.0)):
                    flanks = (weight > 0.5) & (sign * t > options.flank_area_z)
                    flanks &= sign * baseline > np.float32(lod95)
                    change |= _touching(flanks, change)
                del t, weight
            del baseline
    significance[loss] = LOSS
    significance[gain] = GAIN
    del centred, loss, gain, sigma
    lod_values = lod[valid]
    lod_median = float(np.median(lod_values))
    write_geotiff(dh_out, dh, transform, crs)
    write_geotiff(Path(dh_out).parent / LOD_FILE, lod, transform, crs)
    write_text_atomic(Path(dh_out).parent / ERROR_MODEL_FILE, json.dumps(model.to_dict(), indent=1))
    tags = {"LOD_M": repr(lod_median)}
    if floored:
        # The baseline's own test, so that its regions can be judged as the baseline
        # judges them (change_regions.baseline_surface_changes).
        tags |= {
            BASELINE_MEDIAN_TAG: repr(float(median)),
            BASELINE_LOD_TAG: repr(float(lod95)),
            BASELINE_CORRELATION_TAG: repr(baseline_length),
        }
    write_geotiff(significance_out, significance, transform, crs, tags=tags)
    progress(1.0)
    return DifferenceResult(
        nmad_m=nmad,
        lod95_m=lod95,
        lod_m=lod_median,
        lod_p10_m=float(np.percentile(lod_values, 10)),
        lod_p90_m=float(np.percentile(lod_values, 90)),
        error_model=kind,
        correlation_length_m=float(model.correlation_length_m),
        baseline_correlation_length_m=baseline_length,
        sigma_by_slope=[
            [round(s, 1), round(v, 4)]
            for s, v in zip(model.slope_centres_deg, model.sigma_table[0], strict=True)
        ],
        median_dh_m=float(model.median_dh_m),
        stable_pixels=int(model.stable_pixels),
        significant_loss_pixels=int(np.count_nonzero(significance == LOSS)),
        significant_gain_pixels=int(np.count_nonzero(significance == GAIN)),
        pixel_area_m2=float(abs(transform.a * transform.e)),
        seconds=time.perf_counter() - start,
    )


def _touching(candidates: np.ndarray, core: np.ndarray) -> np.ndarray:
    """The candidate pixels 8-connected to `core`, directly or through other candidates."""
    labels, count = ndimage.label(candidates, structure=np.ones((3, 3), dtype=bool))
    if not count:
        return candidates
    dilated = ndimage.binary_dilation(core, structure=np.ones((3, 3), dtype=bool))
    hit = np.zeros(count + 1, dtype=bool)
    hit[np.unique(labels[dilated & candidates])] = True
    hit[0] = False
    return hit[labels]


def read_error_model(work_dir: Path) -> ErrorModel:
    """The error model the difference stage wrote into `work_dir`."""
    return ErrorModel.from_dict(json.loads((Path(work_dir) / ERROR_MODEL_FILE).read_text()))


def _error_model(
    dh: np.ndarray,
    slope: np.ndarray,
    curvature: np.ndarray,
    pixel_size: float,
    stable: np.ndarray,
    median: float,
    nmad: float,
    options: DifferenceOptions,
    floored: bool,
) -> tuple[ErrorModel, np.ndarray, float | None]:
    """The error model, its sigma_dh per pixel (float32) and, where the LoD is floored
    at the simple baseline's, the baseline's correlation length (else None)."""
    model_options = ErrorModelOptions(
        attribute_scale_m=options.attribute_scale_m,
        strong_change_lod_ratio=options.strong_change_lod_ratio,
    )
    if options.error_model == "heteroscedastic":
        try:
            # Floored, the fit's first round looks for stable terrain where the baseline
            # does, and so is the baseline's own fit: its correlation length keeps the
            # default's minimum area from going below the baseline's
            # (change_regions.min_area_m2).
            model, sigma, first = fit_error_model(
                dh, slope, curvature, pixel_size, model_options,
                first_candidates=stable if floored else None,
            )  # fmt: skip
        except ValueError as exc:
            raise InputError(f"cannot learn the error of the difference: {exc}") from None
        return model, sigma, float(first.correlation_length_m) if floored else None
    # The uniform baseline: one sigma everywhere, as it always was; the variogram of a
    # single fit still gives intervals.
    model_options.strong_change_lod_ratio = None
    model = fit_error_model(
        dh, slope, curvature, pixel_size, model_options, candidate_stable=stable
    ).model
    model.slope_centres_deg = [0.0]
    model.curvature_centres = [0.0]
    model.sigma_table = [[max(nmad, 1e-6)]]
    model.counts = [[int(np.count_nonzero(stable))]]
    model.median_dh_m = median
    model.nmad_m = nmad
    model.stable_pixels = int(np.count_nonzero(stable))
    return model, model.sigma(slope, curvature), None


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
