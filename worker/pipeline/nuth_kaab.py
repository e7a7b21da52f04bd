"""Nuth & Kääb (2011) horizontal co-registration of two DSMs on one grid, vectorised.

The iteration is xdem's `NuthKaab` (0.2): slope and aspect of the reference from its
gradient; at each step, the difference at the sampled pixels with the other DSM moved by
the current shift (bilinear), less its median, divided by the slope's tangent; its median
in 72 equal bins of aspect; `a cos(b - aspect) + c` fitted to the bins; the shift moved by
`(a sin b, a cos b)` pixels, until that step is below the tolerance (after three steps at
least). xdem takes each bin's median through scipy with a Python callable (binned.py):
0.1-0.3 s a step on 200 000 samples, and 20 steps where a pair does not converge to the
tolerance, which made it most of a comparison's time. Here a step is one sort and a
linear least-squares fit (the cosine is linear in `a cos b`, `a sin b` and `c`, so its
optimum is the one xdem's curve fit reaches).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from worker.pipeline.binned import bin_index, binned_median
from worker.pipeline.sampling import sorted_sample

ASPECT_BINS = 72


class NuthKaabError(ValueError):
    """Nothing left to fit: too few samples with a slope, or the shift left the grid."""


def nuth_kaab_shift(
    reference: np.ndarray,
    moving: np.ndarray,
    inliers: np.ndarray,
    pixel_size: tuple[float, float],
    *,
    max_iterations: int,
    tolerance_px: float,
    subsample: int,
    seed: int,
) -> tuple[float, float]:
    """The shift (east, north) in metres that, applied to `moving`, lays it on `reference`.

    Both arrays are on the same north-up grid of `pixel_size` (x, y; positive) metres;
    `inliers` (bool) marks the stable terrain the fit may use.
    """
    res_x, res_y = pixel_size
    grad_rows, grad_cols = np.gradient(reference.astype(np.float64))
    slope_tan = np.hypot(grad_cols, grad_rows)
    aspect = np.arctan2(-grad_cols, grad_rows) + np.pi
    usable = inliers & np.isfinite(reference) & np.isfinite(moving) & np.isfinite(slope_tan)
    usable &= ~np.isclose(slope_tan, 0.0)
    index = np.flatnonzero(usable.ravel())
    if index.size == 0:
        raise NuthKaabError("no stable pixel with a slope to fit the shift on")
    if index.size > subsample:
        index = sorted_sample(np.random.default_rng(seed), index, subsample)
    rows, cols = np.unravel_index(index, reference.shape)
    ref_values = reference.ravel()[index].astype(np.float64)
    tan_values, aspect_values = slope_tan.ravel()[index], aspect.ravel()[index]
    moving64 = moving.astype(np.float64)

    east = north = 0.0  # metres, the offset of the moving DSM's coordinates
    for step in range(max(max_iterations, 1)):
        sampled = ndimage.map_coordinates(
            moving64,
            [rows - north / res_y, cols + east / res_x],
            order=1,
            mode="constant",
            cval=np.nan,
            prefilter=False,
        )
        dh = ref_values - sampled
        valid = np.isfinite(dh)
        if not valid.any():
            raise NuthKaabError("the shift moved every sample off the grid")
        dh = dh[valid] - np.median(dh[valid])
        d_east, d_north = _cosine_fit(dh / tan_values[valid], aspect_values[valid])
        east += d_east * res_x
        north += d_north * res_y
        if step > 1 and np.hypot(d_east, d_north) < tolerance_px:
            break
    return -east, -north


def _cosine_fit(values: np.ndarray, aspect: np.ndarray) -> tuple[float, float]:
    """(a sin b, a cos b) of `a cos(b - aspect) + c` fitted to the medians of `values` in
    equal bins of aspect over its range (bin centres as the abscissa)."""
    low, high = float(aspect.min()), float(aspect.max())
    if high <= low:
        raise NuthKaabError("every sample faces the same way: no horizontal shift to fit")
    edges = np.linspace(low, high, ASPECT_BINS + 1)
    counts, medians = binned_median(values, bin_index(aspect, edges), ASPECT_BINS)
    filled = counts > 0
    centres = 0.5 * (edges[:-1] + edges[1:])[filled]
    design = np.column_stack([np.cos(centres), np.sin(centres), np.ones_like(centres)])
    (a_cos_b, a_sin_b, _), *_ = np.linalg.lstsq(design, medians[filled], rcond=None)
    return float(a_sin_b), float(a_cos_b)
