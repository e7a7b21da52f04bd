"""The error of a DSM difference, learned from stable terrain (Hugonnet et al. 2022).

Two surveys of the same ground differ by more on steep and rough ground than on flat
ground (a residual horizontal shift s gives |dh| ~ s * tan(slope)), and neighbouring
pixels share their error (doming, strip steps, smoothing). One NMAD for the whole raster
is therefore too strict on flat ground and far too loose on steep slopes. This module
fits, from the difference itself:

- **heteroscedasticity**: sigma_dh as a function of slope and curvature, the NMAD of dh
  in bins of both (as xdem.spatialstats.nd_binning gives it, by one sort: binned.py),
  made non-decreasing in each by isotonic regression so that one contaminated bin cannot
  lower a steeper one, and interpolated per pixel;
- **spatial correlation**: the empirical variogram of the standardised difference
  z = (dh - median) / sigma_dh (all pixel pairs, by FFT) and a fit of a nugget plus two
  spherical models (a short and a long range);
- **the effective number of samples** of an area (Rolstad et al. 2009 for a disk, by
  numerical integration of the correlation over the distances within the disk), which
  turns a pixel sigma into the uncertainty of an area's mean dh and of its volume.

Stable terrain is every valid pixel not excluded as change: the fit is repeated with
pixels more than `exclusion_z` sigmas from the median (grown by a few pixels) left out,
so a landslide or a felled tree does not inflate its bin. The coregistration's stable
mask is not used: it excludes by one global NMAD, which would cut the tails of steep
bins and understate their error. Then regions whose |dh| averages twice their LoD
(`strong_change_lod_ratio`) are left out whole, grown by half the correlation
length, and the table fitted again: a slide's shallow flanks pass the pixel exclusion,
and where change covers much of the steep ground they inflate its bins. The first round
may be limited to the simple baseline's candidates (`first_candidates`): it is then the
baseline's own fit, whose correlation length the default's minimum area is never
below; it only finds the strong change, and the table kept is fitted over every pixel.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy import ndimage, optimize

from worker.pipeline.binned import bin_index, binned_mean, binned_nmad
from worker.pipeline.binned import nmad as robust_nmad
from worker.pipeline.sampling import sorted_sample

LOD_Z = 1.96  # two-sided 95 % for a normal error
SLOPE_EDGES_DEG = (0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0, 60.0, 70.0, 90.0)
# Quantiles of |curvature| that bound its bins.
CURVATURE_QUANTILES: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0)
# Lag bin edges of the empirical variogram, in pixels (upper bounds).
LAG_EDGES_PX = (1.5, 2.5, 3.5, 5, 7, 10, 14, 20, 28, 40, 56, 80, 112, 160, 224, 320, 448)


@dataclass
class ErrorModelOptions:
    min_bin_count: int = 200  # pixels needed for a bin's NMAD to count
    max_samples: int = 400_000  # stable pixels sampled for the binning (seeded)
    exclusion_z: float = 4.0  # a pixel beyond this many sigmas is change, not error
    exclusion_buffer_px: int = 2
    iterations: int = 3
    variogram_window_px: int = 768  # the variogram is computed on a window this large
    attribute_scale_m: float = 0.1  # slope and curvature are measured at this scale
    # Regions of significant change whose |dh| averages this many times their LoD are left
    # out (grown by half the errors' correlation length) and the table fitted again; None:
    # fitted once. Twice: patches of correlated error average 1.2-1.7 times their LoD.
    strong_change_lod_ratio: float | None = 2.0
    strong_change_min_px: int = 64
    seed: int = 0


@dataclass
class VariogramModel:
    """gamma(h) = nugget + sum_k psill_k * spherical(h, range_k), h in metres, for z."""

    nugget: float
    ranges_m: list[float]
    psills: list[float]

    @property
    def sill(self) -> float:
        return self.nugget + sum(self.psills)

    def correlation(self, h_m: np.ndarray) -> np.ndarray:
        """Correlation at lag h (> 0): the share of variance still shared at that lag."""
        h = np.asarray(h_m, dtype=float)
        shared = np.zeros_like(h)
        for r, c in zip(self.ranges_m, self.psills, strict=True):
            shared += c * (1.0 - _spherical(h, r))
        return shared / max(self.sill, 1e-12)

    def gamma(self, h_m: np.ndarray) -> np.ndarray:
        h = np.asarray(h_m, dtype=float)
        out = np.full_like(h, self.nugget)
        for r, c in zip(self.ranges_m, self.psills, strict=True):
            out += c * _spherical(h, r)
        return np.where(h > 0, out, 0.0)


@dataclass
class ErrorModel:
    """sigma_dh per pixel from slope and curvature; the correlation of the errors."""

    pixel_size: float
    slope_centres_deg: list[float]
    curvature_centres: list[float]  # |curvature| in 1/100 m (xdem's unit)
    sigma_table: list[list[float]]  # [curvature bin][slope bin], metres
    median_dh_m: float
    nmad_m: float  # of all stable pixels, as the single-number model would use
    stable_pixels: int
    variogram: VariogramModel
    counts: list[list[int]] = field(default_factory=list)

    def sigma(self, slope_deg: np.ndarray, curvature: np.ndarray) -> np.ndarray:
        """sigma_dh (m, float32) at each pixel; NaN where slope or curvature are NaN.

        Bilinear on the bin centres, constant beyond the outer ones: each pixel's
        fractional position among the centres along each axis, then the table read at
        the four corners (padded by its last row and column so the upper corner always
        exists). It runs once per fitting round over every pixel, so it works through
        the raster in bands that stay in the processor's cache.
        """
        slope_deg = np.asarray(slope_deg)
        curvature = np.asarray(curvature)
        table = np.asarray(self.sigma_table, dtype=np.float32)
        padded = np.pad(table, ((0, 1), (0, 1)), mode="edge").ravel()
        width = table.shape[1] + 1
        out = np.empty(slope_deg.shape, dtype=np.float32)
        flat_slope, flat_curv, flat_out = (
            slope_deg.reshape(-1),
            curvature.reshape(-1),
            out.reshape(-1),
        )
        for start in range(0, flat_out.size, _SIGMA_BAND):
            part = slice(start, start + _SIGMA_BAND)
            flat_out[part] = _bilinear(
                padded,
                width,
                self.slope_centres_deg,
                self.curvature_centres,
                flat_slope[part],
                flat_curv[part],
            )
        return out

    @property
    def correlation_length_m(self) -> float:
        """The short range of the errors' correlation (at least one pixel)."""
        ranges = [
            r
            for r, c in zip(self.variogram.ranges_m, self.variogram.psills, strict=True)
            if c > 0.05 * self.variogram.sill
        ]
        return max(min(ranges) if ranges else self.pixel_size, self.pixel_size)

    def mean_error_factor(self, area_m2: float) -> float:
        """sqrt(1 / n_eff): the sigma of an area's mean dh in units of the pixel sigma."""
        return 1.0 / math.sqrt(self.effective_samples(area_m2))

    def effective_samples(self, area_m2: float) -> float:
        """Effective number of independent samples of a disk-shaped area (>= 1)."""
        pixels = max(area_m2 / self.pixel_size**2, 1.0)
        radius = math.sqrt(max(area_m2, self.pixel_size**2) / math.pi)
        v = self.variogram
        # var(mean) / sigma^2 = (1/N^2) sum_ij rho(d_ij) = 1/N + (1 - 1/N) * mean rho over
        # pairs of distinct points; the nugget is uncorrelated at any lag > 0.
        r = np.linspace(0.0, 2 * radius, 513)[1:]
        u = r / (2 * radius)
        # Distance density between two uniform points of a disk of radius R.
        density = (4 * r / (math.pi * radius**2)) * (np.arccos(u) - u * np.sqrt(1 - u * u))
        weights = density * (r[1] - r[0])
        weights /= weights.sum()
        correlated = float(np.sum(weights * v.correlation(r)))
        share = 1.0 / pixels + (1.0 - 1.0 / pixels) * correlated
        share = max(share, 1.0 / pixels)
        return float(min(1.0 / share, pixels))

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["correlation_length_m"] = self.correlation_length_m
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ErrorModel:
        data = dict(data)
        data.pop("correlation_length_m", None)
        data["variogram"] = VariogramModel(**data["variogram"])
        return cls(**data)


# Pixels per band of ErrorModel.sigma: a few MB per temporary array.
_SIGMA_BAND = 1 << 18


def area_t(
    z: np.ndarray, model: ErrorModel, pixel_size: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Around each pixel, over a square of the errors' correlation size: the mean of the
    standardised difference z, that mean in units of its own standard error (sqrt(n_eff)
    under the variogram), and the share of the square that has data."""
    valid = np.isfinite(z)
    length = max(model.correlation_length_m, 3 * pixel_size)
    radius_px = int(min(max(math.ceil(length / pixel_size), 3), 64))
    size = 2 * radius_px + 1
    filled = np.where(valid, z, 0.0).astype(np.float32)
    weight = ndimage.uniform_filter(valid.astype(np.float32), size, mode="constant")
    mean = ndimage.uniform_filter(filled, size, mode="constant") / np.maximum(weight, 1e-6)
    t = mean / np.float32(model.mean_error_factor((size * pixel_size) ** 2))
    return mean, t, weight


def _bilinear(
    padded: np.ndarray,
    width: int,
    slope_centres: list[float],
    curvature_centres: list[float],
    slope_deg: np.ndarray,
    curvature: np.ndarray,
) -> np.ndarray:
    """Bilinear lookup of a flattened, edge-padded [curvature][slope] table (1-D inputs)."""
    s_pos = _bin_position(slope_deg, slope_centres)
    c_pos = _bin_position(np.abs(curvature), curvature_centres)
    s_low = s_pos.astype(np.int32)
    c_low = c_pos.astype(np.int32)
    s_frac = s_pos - s_low
    c_frac = c_pos - c_low
    corner = c_low * width + s_low
    low = padded[corner]
    low += s_frac * (padded[corner + 1] - low)
    high = padded[corner + width]
    high += s_frac * (padded[corner + width + 1] - high)
    low += c_frac * (high - low)
    low[~(np.isfinite(slope_deg) & np.isfinite(curvature))] = np.nan
    return low


def _bin_position(values: np.ndarray, centres: list[float]) -> np.ndarray:
    """Fractional index of each value among the bin centres (0 to n - 1, clamped), float32;
    NaN reads as the first bin (the caller masks it)."""
    finite = np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0)
    return np.interp(finite, centres, np.arange(len(centres), dtype=float)).astype(np.float32)


def terrain_attributes(
    dsm: np.ndarray, pixel_size: float, scale_m: float = 0.1
) -> tuple[np.ndarray, np.ndarray]:
    """Slope (degrees) and |curvature| (1/100 m, the Laplacian) of a DSM, NaN where none.

    Both are measured on the DSM smoothed at `scale_m` (at least one pixel): on a 2 cm
    DSM, pixel noise alone would otherwise read as 40-degree slopes; and at least two
    pixels, so that a pixel's own error barely moves its attributes (which would let
    the binning pick out noisy pixels by their noise).
    """
    valid = np.isfinite(dsm)
    if not valid.any():
        nan = np.full(dsm.shape, np.nan, dtype=np.float32)
        return nan, nan.copy()
    filled = _fill_nearest(dsm, valid)
    sigma_px = float(np.clip(scale_m / pixel_size, 2.0, 8.0))
    smooth = ndimage.gaussian_filter(filled.astype(np.float64), sigma_px, mode="nearest")
    # Slope in float32 (three to four times faster) on heights about the middle of the
    # relief, so rounding stays below 1e-4 m for a relief of a kilometre.
    middle = 0.5 * (float(smooth.min()) + float(smooth.max()))
    gy, gx = np.gradient((smooth - middle).astype(np.float32), np.float32(pixel_size))
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    del gy, gx
    # Curvature (second derivatives) amplifies noise far more than slope: twice the scale.
    smoother = ndimage.gaussian_filter(smooth, sigma_px * np.sqrt(3.0), mode="nearest")
    lap = ndimage.laplace(smoother) / pixel_size**2 * 100.0
    curvature = np.abs(lap).astype(np.float32)
    slope[~valid] = np.nan
    curvature[~valid] = np.nan
    return slope, curvature


class ErrorModelFit(NamedTuple):
    """What `fit_error_model` returns."""

    model: ErrorModel
    sigma: np.ndarray  # sigma_dh per pixel, float32
    first_round: ErrorModel  # the model of the fit's first round


def fit_error_model(
    dh: np.ndarray,
    slope_deg: np.ndarray,
    curvature: np.ndarray,
    pixel_size: float,
    options: ErrorModelOptions | None = None,
    candidate_stable: np.ndarray | None = None,
    first_candidates: np.ndarray | None = None,
) -> ErrorModelFit:
    """Fit sigma_dh(slope, curvature) and the variogram of the standardised difference:
    the model, its sigma_dh at every pixel (float32), which the fit computes anyway (a
    second pass over a large raster costs seconds), and the model of its first round.

    `candidate_stable` (optional, bool) limits where stable terrain may be looked for
    (e.g. outside a user's known active area); change is excluded within it regardless.
    `first_candidates` (optional, bool) limits it in the first round only, where that
    leaves enough pixels: with the simple baseline's candidates and no strong-change
    rule, that round is the baseline's own fit (difference.py), and the default learns
    the baseline's correlation length at no cost.
    """
    options = options or ErrorModelOptions()
    valid = np.isfinite(dh) & np.isfinite(slope_deg) & np.isfinite(curvature)
    if candidate_stable is not None:
        valid &= candidate_stable
    if np.count_nonzero(valid) < options.min_bin_count:
        raise ValueError("too few valid pixels to learn the error of the difference")
    first, limited = valid, False
    if first_candidates is not None:
        within = valid & first_candidates
        if np.count_nonzero(within) >= options.min_bin_count:
            first, limited = within, True
    rng = np.random.default_rng(options.seed)
    model, sigma, z, stable = _fit_table(
        dh, slope_deg, curvature, first, first.copy(), pixel_size, rng, options
    )
    model.variogram = _fit_variogram(z, stable, pixel_size, options)
    first_round = model
    strong = (
        _strong_change(dh, sigma, valid, model, options)
        if options.strong_change_lod_ratio is not None
        else np.zeros(dh.shape, dtype=bool)
    )
    # Fitted again without the strong change, or over all of `valid` where the first
    # round looked only within `first_candidates` (a co-registration's stable mask may
    # leave out the steep ground the table needs).
    if strong.any() or limited:
        start = valid.copy()
        if strong.any():
            buffer_px = int(
                min(max(math.ceil(0.5 * model.correlation_length_m / pixel_size), 2), 64)
            )
            start &= ~(ndimage.maximum_filter(strong.view(np.uint8), size=2 * buffer_px + 1) > 0)
        # Its samples drawn from the seed afresh: without strong change it is then the
        # fit an unrestricted first round would have been.
        rng = np.random.default_rng(options.seed)
        model, sigma, z, stable = _fit_table(
            dh, slope_deg, curvature, valid, start, pixel_size, rng, options
        )
        model.variogram = _fit_variogram(z, stable, pixel_size, options)
    return ErrorModelFit(model, sigma, first_round)


def _strong_change(
    dh: np.ndarray,
    sigma: np.ndarray,
    valid: np.ndarray,
    model: ErrorModel,
    options: ErrorModelOptions,
) -> np.ndarray:
    """Regions beyond their LoD whose |dh| averages strong_change_lod_ratio LoDs or more."""
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.abs(dh - np.float32(model.median_dh_m)) / (np.float32(LOD_Z) * sigma)
    significant = valid & (ratio > 1.0)
    significant = ndimage.binary_opening(significant, structure=np.ones((3, 3), bool))
    labels, count = ndimage.label(significant, structure=np.ones((3, 3), bool))
    if not count:
        return significant
    sizes, mean = binned_mean(ratio[significant], labels[significant], count + 1)
    keep = (sizes >= options.strong_change_min_px) & (mean >= options.strong_change_lod_ratio)
    keep[0] = False
    return keep[labels]


def _fit_table(
    dh: np.ndarray,
    slope_deg: np.ndarray,
    curvature: np.ndarray,
    valid: np.ndarray,
    stable: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    options: ErrorModelOptions,
) -> tuple[ErrorModel, np.ndarray, np.ndarray, np.ndarray]:
    """The sigma table refitted with pixels beyond exclusion_z left out, from `stable`:
    the model, its sigma, z, and the stable pixels of the last round."""
    model: ErrorModel | None = None
    sigma: np.ndarray | None = None
    for _ in range(max(options.iterations, 1)):
        model = _fit_heteroscedasticity(dh, slope_deg, curvature, stable, pixel_size, rng, options)
        sigma = model.sigma(slope_deg, curvature)
        with np.errstate(invalid="ignore", divide="ignore"):
            z = (dh - np.float32(model.median_dh_m)) / sigma
        change = valid & (np.abs(z) > options.exclusion_z)
        if options.exclusion_buffer_px > 0 and change.any():
            change = ndimage.binary_dilation(change, iterations=options.exclusion_buffer_px)
        new_stable = valid & ~change
        if np.count_nonzero(new_stable) < options.min_bin_count:
            break
        if np.array_equal(new_stable, stable):
            break
        stable = new_stable
    assert model is not None and sigma is not None
    return model, sigma, z, stable


def _fit_heteroscedasticity(
    dh: np.ndarray,
    slope: np.ndarray,
    curvature: np.ndarray,
    stable: np.ndarray,
    pixel_size: float,
    rng: np.random.Generator,
    options: ErrorModelOptions,
) -> ErrorModel:
    index = np.flatnonzero(stable.ravel())
    if index.size > options.max_samples:
        index = sorted_sample(rng, index, options.max_samples)
    values = dh.ravel()[index].astype(np.float64)
    s = slope.ravel()[index].astype(np.float64)
    c = curvature.ravel()[index].astype(np.float64)
    median = float(np.median(values))
    nmad = robust_nmad(values)
    curv_edges = np.unique(np.quantile(c, CURVATURE_QUANTILES))
    if curv_edges.size < 2:
        curv_edges = np.array([c.min(), c.min() + 1e-9])
    curv_edges[-1] += 1e-9
    slope_edges = np.asarray(SLOPE_EDGES_DEG, dtype=float)
    n_s, n_c = slope_edges.size - 1, curv_edges.size - 1
    i_s, i_c = bin_index(s, slope_edges), bin_index(c, curv_edges)
    cell = np.where((i_s >= 0) & (i_c >= 0), i_c * n_s + i_s, -1)
    counts, nmads = binned_nmad(values - median, cell, n_c * n_s)
    cnt = counts.reshape(n_c, n_s)
    sig = np.where(cnt >= options.min_bin_count, nmads.reshape(n_c, n_s), np.nan)
    # Keep only slope bins that hold data at all; empty ones would be pure extrapolation.
    used = cnt.sum(axis=0) > 0
    slope_centres = 0.5 * (slope_edges[:-1] + slope_edges[1:])
    curv_centres = 0.5 * (curv_edges[:-1] + curv_edges[1:])
    sig, cnt, slope_centres = sig[:, used], cnt[:, used], slope_centres[used]
    sig = _fill_and_make_monotone(sig, cnt, fallback=max(nmad, 1e-6))
    return ErrorModel(
        pixel_size=float(pixel_size),
        slope_centres_deg=[float(v) for v in slope_centres],
        curvature_centres=[float(v) for v in curv_centres],
        sigma_table=sig.tolist(),
        median_dh_m=median,
        nmad_m=nmad,
        stable_pixels=int(np.count_nonzero(stable)),
        variogram=VariogramModel(nugget=1.0, ranges_m=[], psills=[]),
        counts=cnt.tolist(),
    )


def _fill_and_make_monotone(sig: np.ndarray, cnt: np.ndarray, fallback: float) -> np.ndarray:
    """Fill bins with too few pixels, then make sigma non-decreasing along both axes."""
    out = sig.copy()
    if np.all(np.isnan(out)):
        return np.full_like(out, fallback)
    # Fill a missing bin from its curvature row (nearest slope bin with data), else from
    # the pooled column of its slope bin, else the overall value.
    for i in range(out.shape[0]):
        have = np.flatnonzero(np.isfinite(out[i]))
        if have.size:
            missing = np.flatnonzero(np.isnan(out[i]))
            out[i, missing] = np.interp(missing, have, out[i, have])
    column = np.nanmedian(np.where(np.isfinite(out), out, np.nan), axis=0)
    column = np.where(np.isfinite(column), column, fallback)
    out = np.where(np.isfinite(out), out, column[None, :])
    out = _monotone_both_axes(out, np.maximum(cnt, 1).astype(float))
    return np.maximum(out, 1e-6)


def _monotone_both_axes(
    values: np.ndarray, weights: np.ndarray, iterations: int = 100
) -> np.ndarray:
    """The table nearest to `values` (weighted least squares) that is non-decreasing
    along both axes: Dykstra's alternating projections onto the row- and the
    column-monotone tables. One pass along each axis is not enough: pooling a column
    can undo a row's order (a steep bin then reads lower than a gentler one).
    A running maximum along both axes removes what the iterations leave below their
    tolerance, so the result is exactly monotone."""
    x = values.astype(float).copy()
    p = np.zeros_like(x)
    q = np.zeros_like(x)
    for _ in range(iterations):
        y = x + p
        z = np.stack([_isotonic(row, w) for row, w in zip(y, weights, strict=True)])
        p = y - z
        y = z + q
        new = np.stack([_isotonic(col, w) for col, w in zip(y.T, weights.T, strict=True)], axis=1)
        q = y - new
        done = np.allclose(new, x, rtol=0.0, atol=1e-9)
        x = new
        if done:
            break
    return np.maximum.accumulate(np.maximum.accumulate(x, axis=1), axis=0)


def _isotonic(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted non-decreasing least-squares fit (pool adjacent violators)."""
    blocks: list[list[float]] = []  # [mean, weight, length]
    for v, w in zip(values, weights, strict=True):
        blocks.append([float(v), float(w), 1])
        while len(blocks) > 1 and blocks[-2][0] > blocks[-1][0]:
            m2, w2, n2 = blocks.pop()
            m1, w1, n1 = blocks.pop()
            blocks.append([(m1 * w1 + m2 * w2) / (w1 + w2), w1 + w2, n1 + n2])
    return np.concatenate([np.full(int(n), m) for m, _, n in blocks])


def empirical_variogram(
    z: np.ndarray, mask: np.ndarray, pixel_size: float, window_px: int = 768
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lags_m, gamma, pair_counts) of z over all pixel pairs inside `mask`, by FFT.

    The window of `window_px` with the most masked pixels is used (the variogram of a
    larger raster is estimated from it); lags are binned by LAG_EDGES_PX.
    """
    r0, c0 = _best_window(mask, window_px)
    zz = np.where(mask, z, 0.0)[r0 : r0 + window_px, c0 : c0 + window_px].astype(np.float64)
    m = mask[r0 : r0 + window_px, c0 : c0 + window_px].astype(np.float64)
    h, w = m.shape
    shape = (2 * h, 2 * w)

    def corr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        fa = np.fft.rfft2(a, shape)
        fb = np.fft.rfft2(b, shape)
        return np.fft.irfft2(np.conj(fa) * fb, shape)

    # sum over pairs (x, x+h) of m m (z(x+h) - z(x))^2 = C(m z^2, m) + C(m, m z^2) - 2 C(mz, mz)
    count = corr(m, m)
    sq = corr(m * zz**2, m) + corr(m, m * zz**2) - 2 * corr(zz, zz)
    dy = np.fft.fftfreq(shape[0], 1.0 / shape[0])[:, None]
    dx = np.fft.fftfreq(shape[1], 1.0 / shape[1])[None, :]
    dist = np.hypot(dy, dx)
    edges = np.array([e for e in LAG_EDGES_PX if e <= min(h, w) / 2] or [LAG_EDGES_PX[0]])
    lags, gammas, counts = [], [], []
    lower = 0.5
    for upper in edges:
        sel = (dist > lower) & (dist <= upper)
        n = float(np.rint(count[sel]).sum())
        if n >= 50:
            lags.append(float(np.sum(dist[sel] * count[sel]) / max(count[sel].sum(), 1e-9)))
            gammas.append(float(0.5 * sq[sel].sum() / n))
            counts.append(n)
        lower = upper
    return (
        np.asarray(lags) * pixel_size,
        np.asarray(gammas),
        np.asarray(counts),
    )


def _fit_variogram(
    z: np.ndarray, stable: np.ndarray, pixel_size: float, options: ErrorModelOptions
) -> VariogramModel:
    mask = stable & np.isfinite(z)
    lags, gamma, counts = empirical_variogram(z, mask, pixel_size, options.variogram_window_px)
    if lags.size < 3:
        return VariogramModel(nugget=1.0, ranges_m=[], psills=[])
    sill = float(np.median(gamma[-3:])) if gamma.size >= 3 else float(gamma[-1])
    sill = max(sill, 1e-6)
    max_lag = float(lags[-1])

    def model(h: np.ndarray, n: float, c1: float, r1: float, c2: float, r2: float) -> np.ndarray:
        return n + c1 * _spherical(h, r1) + c2 * _spherical(h, r2)

    lo = [0.0, 0.0, pixel_size, 0.0, pixel_size]
    hi = [2 * sill, 2 * sill, max(max_lag / 4, 2 * pixel_size), 2 * sill, 2 * max_lag]
    p0 = [0.3 * sill, 0.5 * sill, min(3 * pixel_size, hi[2] * 0.9), 0.2 * sill, max_lag / 3]
    p0 = [min(max(v, a + 1e-9), b - 1e-9) for v, a, b in zip(p0, lo, hi, strict=True)]
    try:
        params, _ = optimize.curve_fit(
            model, lags, gamma, p0=p0, bounds=(lo, hi), sigma=1.0 / np.sqrt(counts), maxfev=20000
        )
    except (RuntimeError, ValueError):
        return VariogramModel(nugget=sill, ranges_m=[], psills=[])
    n, c1, r1, c2, r2 = (float(v) for v in params)
    (r1, c1), (r2, c2) = sorted([(r1, c1), (r2, c2)])
    return VariogramModel(nugget=n, ranges_m=[r1, r2], psills=[c1, c2])


def _spherical(h: np.ndarray, r: float) -> np.ndarray:
    x = np.minimum(np.asarray(h, dtype=float) / max(r, 1e-12), 1.0)
    return 1.5 * x - 0.5 * x**3


def _best_window(mask: np.ndarray, size: int) -> tuple[int, int]:
    h, w = mask.shape
    if h <= size and w <= size:
        return 0, 0
    step = max(size // 4, 1)
    best, where = -1, (0, 0)
    integral = np.pad(mask.astype(np.int64).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    for r in range(0, max(h - size, 0) + 1, step):
        for c in range(0, max(w - size, 0) + 1, step):
            r1, c1 = min(r + size, h), min(c + size, w)
            total = integral[r1, c1] - integral[r, c1] - integral[r1, c] + integral[r, c]
            if total > best:
                best, where = int(total), (r, c)
    return where


def _fill_nearest(array: np.ndarray, valid: np.ndarray) -> np.ndarray:
    if valid.all():
        return array
    index = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    return array[tuple(index)]
