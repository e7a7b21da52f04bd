"""Co-register the post DSM to the pre DSM on stable terrain.

Model: corrected_post(x, y) = post(x - east, y - north) - plane(x, y), where (east, north)
is the horizontal correction found by Nuth & Kääb (2011) (nuth_kaab.py: xdem's NuthKaab
iteration, vectorised) and plane = a + b (x - xc) + c (y - yc) the vertical correction: a
constant offset, plus a tilt when `tilt` is on. The reported shift (shift_east_m,
shift_north_m, shift_up_m) is the correction applied to post: the opposite of post's
displacement relative to pre; shift_up_m is the vertical correction at the grid centre.

Stable terrain is refined iteratively so a landslide does not bias the fit: fit on the
current stable mask, compute dh = corrected_post - pre, drop pixels with
|dh - median| > k * NMAD or |dh| > max_abs_change_m (grown by a few pixels), refit.

Photogrammetric doming (a bowl or dome over the survey, from a slightly wrong lens
model) is removed the same way when `dome` is on: quadratic terms d (x - xc)^2 +
e (y - yc)^2 + f (x - xc)(y - yc) join the plane, fitted on stable terrain; left in, a
dome of a few centimetres over the survey reads as a wide, shallow change.

The tilt is a least-squares plane fitted with numpy rather than xdem's Deramp: in xdem
0.2.3 Deramp(poly_order=1) fits c00 + c01 y + c10 x + c11 x y, which adds a twist term
that is not a tilt. The tilt is removed from post before each Nuth & Kääb fit, because a
tilt left in dh biases the horizontal estimate (measured: 1 m/km gave 0.04 px of bias).

A rotation of post about the grid centre (an uncorrected heading of a few tenths of a
degree moves the edges of a survey by decimetres, enough to read as change on steep
ground) is estimated when `rotation` is on, after Nuth & Kääb: a least-squares surface
match linearised in the horizontal motion (Gruen & Akca 2005),
dh = dz/dx (tx - theta (y - yc)) + dz/dy (ty + theta (x - xc)) + plane(x, y), solved on
stable terrain with the slopes of the pre surface, applied, and repeated; it is kept
only when it lowers the spread of dh on stable terrain. The correction then reads: a
feature of post at q lands at R(theta) (q - c) + c + t.

Flat terrain (too few pixels steeper than `min_slope_deg`) carries no horizontal
information; then only the vertical correction (and tilt) is estimated.

Nuth & Kääb converges only from closer than the terrain's features are wide: two
stand-alone GNSS flights can be metres apart. A first shift by phase correlation
(coarse_shift.py) is therefore applied before it when the DSMs agree better with it
than without; Nuth & Kääb refines from there (`initial_shift_*` in the result).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine
from scipy import ndimage

from worker.pipeline.binned import nmad
from worker.pipeline.coarse_shift import coarse_shift
from worker.pipeline.errors import InputError
from worker.pipeline.geo import is_metric_projected
from worker.pipeline.nuth_kaab import NuthKaabError, nuth_kaab_shift
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.raster_io import MASK_NODATA, read_elevation, warp_elevation, write_geotiff
from worker.pipeline.stages import StageResult

STABLE, UNSTABLE = 1, 0  # values of the stable-terrain mask file; 255 = nodata in either DSM


@dataclass
class CoregisterOptions:
    tilt: bool = True
    dome: bool = True  # quadratic terms with the tilt (needs tilt)
    max_iterations: int = 4  # stable-terrain refinement rounds
    outlier_nmad_factor: float = 4.0  # k in |dh - median| > k * NMAD
    max_abs_change_m: float = 5.0
    unstable_buffer_px: int = 2  # grow excluded areas so their fringes are excluded too
    min_slope_deg: float = 5.0
    min_sloped_fraction: float = 0.1  # below this the terrain counts as flat
    # Both DSMs are smoothed alike before Nuth & Kaab: a translation commutes with the
    # smoothing, and pixel noise no longer dominates the slopes of fine-resolution DSMs.
    smoothing_px: float = 2.0
    nuth_kaab_max_iterations: int = 20
    nuth_kaab_tolerance_px: float = 0.005  # step size that ends the iterations
    subsample: int = 200_000  # pixels used per fit (measured: same accuracy as 500k)
    min_stable_pixels: int = 1_000
    coarse_shift: bool = True  # phase correlation first (see the module doc)
    rotation: bool = True  # estimate a rotation about the grid centre (module doc)
    rotation_iterations: int = 3
    seed: int = 42


@dataclass
class CoregisterResult(StageResult):
    shift_east_m: float
    shift_north_m: float
    shift_up_m: float
    shift_east_px: float
    shift_north_px: float
    horizontal_estimated: bool
    tilt_east_m_per_km: float | None
    tilt_north_m_per_km: float | None
    tilt_pivot_east_m: float  # map x of the grid centre, where the tilt adds nothing
    tilt_pivot_north_m: float
    nmad_before_m: float
    nmad_after_m: float
    median_before_m: float
    median_after_m: float
    stable_fraction: float
    iterations: int
    notes: list[str]
    seconds: float
    initial_shift_east_m: float = 0.0  # the phase-correlation shift Nuth & Kääb began from
    initial_shift_north_m: float = 0.0
    # Correction's quadratic terms, metres per m^2 about the pivot: (x^2, y^2, x y).
    dome_m_per_m2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dome_range_m: float = 0.0  # largest minus smallest of those terms over the grid
    # Rotation applied to post about the pivot, degrees counter-clockwise (map x east,
    # y north); the shift is applied after it.
    rotation_deg: float = 0.0

    def correct_points(self, points: np.ndarray) -> np.ndarray:
        """Move points (N, 3) of the post survey (map x, y, height) the way the
        correction moved its DSM: a feature of post lands where pre has it."""
        points = np.asarray(points, dtype=np.float64)
        theta = np.radians(self.rotation_deg)
        px, py = points[:, 0] - self.tilt_pivot_east_m, points[:, 1] - self.tilt_pivot_north_m
        x = self.tilt_pivot_east_m + np.cos(theta) * px - np.sin(theta) * py + self.shift_east_m
        y = self.tilt_pivot_north_m + np.sin(theta) * px + np.cos(theta) * py + self.shift_north_m
        tilt_e = (self.tilt_east_m_per_km or 0.0) / 1000.0
        tilt_n = (self.tilt_north_m_per_km or 0.0) / 1000.0
        u, v = x - self.tilt_pivot_east_m, y - self.tilt_pivot_north_m
        qa, qb, qc = self.dome_m_per_m2
        z = points[:, 2] + self.shift_up_m + tilt_e * u + tilt_n * v + qa * u * u
        z = z + qb * v * v + qc * u * v
        return np.column_stack([x, y, z])


@dataclass
class _Plane:
    """a + b dx + c dy + d dx^2 + e dy^2 + f dx dy, metres; dx, dy map offsets from the
    grid centre."""

    a: float = 0.0
    b: float = 0.0
    c: float = 0.0
    d: float = 0.0
    e: float = 0.0
    f: float = 0.0

    def evaluate(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        out = self.a + self.b * dx + self.c * dy
        if self.d or self.e or self.f:
            out = out + self.d * dx * dx + self.e * dy * dy + self.f * dx * dy
        return out

    def shape_only(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Everything but the constant: what is removed from post before Nuth & Kääb."""
        return _Plane(0.0, self.b, self.c, self.d, self.e, self.f).evaluate(dx, dy)


def coregister(
    pre_path: Path,
    post_path: Path,
    post_out: Path,
    options: CoregisterOptions | None = None,
    progress: ProgressFn = no_progress,
    stable_mask_out: Path | None = None,
) -> CoregisterResult:
    """Estimate and apply the correction of post onto pre; both must be on the same grid.

    Writes the corrected post DSM to `post_out` and, if asked, the final stable-terrain
    mask (uint8: 1 stable, 0 excluded, 255 nodata) to `stable_mask_out`.
    """
    options = options or CoregisterOptions()
    start = time.perf_counter()
    pre, profile = read_elevation(pre_path)
    post, post_profile = read_elevation(post_path)
    transform, crs = profile["transform"], profile["crs"]
    if pre.shape != post.shape or post_profile["transform"] != transform:
        raise InputError("pre and post DSMs must be on the same grid: run the align stage first")
    if not is_metric_projected(crs):
        raise InputError("co-registration needs DSMs in a metric CRS: run the align stage first")
    valid = np.isfinite(pre) & np.isfinite(post)
    if np.count_nonzero(valid) < options.min_stable_pixels:
        raise InputError("too few pixels with elevations in both DSMs to co-register them")

    res_x, res_y = abs(transform.a), abs(transform.e)
    dx, dy = _centred_coordinates(transform, pre.shape)
    notes: list[str] = []
    horizontal = _has_horizontal_information(pre, valid, res_x, res_y, options)
    if not horizontal:
        notes.append(
            "flat terrain: too little slope to estimate a horizontal shift; "
            "only the vertical shift was corrected"
        )

    initial, start_post = (0.0, 0.0), post
    if horizontal:
        initial, start_post = _initial_shift(pre, post, transform, crs, options)
    stable = valid & np.isfinite(start_post)
    shift = initial
    plane = _Plane()
    shifted = post
    iterations = 0
    pre_smooth = _smooth(pre, options.smoothing_px)
    for iterations in range(1, options.max_iterations + 1):
        if horizontal:
            post_smooth = _smooth(start_post - plane.shape_only(dx, dy), options.smoothing_px)
            refined = _nuth_kaab(pre_smooth, post_smooth, stable, transform, crs, options)
            shift = (initial[0] + refined[0], initial[1] + refined[1])
        shifted = _apply_shift(post, transform, crs, shift)
        dh = shifted - pre
        plane = _fit_plane(dh, stable, dx, dy, options)
        dh -= plane.evaluate(dx, dy)
        new_stable = _stable_terrain(dh, valid & np.isfinite(dh), stable, options)
        changed = np.count_nonzero(new_stable != stable)
        stable = new_stable
        progress(0.9 * iterations / options.max_iterations)
        if changed <= 1e-4 * stable.size:
            break
    if np.count_nonzero(stable) < options.min_stable_pixels:
        raise InputError("too little stable terrain left to co-register the DSMs")
    theta = 0.0
    if horizontal and options.rotation:
        shift, theta, shifted, plane = _refine_rotation(
            pre, pre_smooth, post, shifted, stable, transform, crs, shift, plane, dx, dy, options
        )

    corrected = (shifted - plane.evaluate(dx, dy)).astype(np.float32)
    write_geotiff(post_out, corrected, transform, crs)
    if stable_mask_out is not None:
        mask = np.where(stable, STABLE, UNSTABLE).astype(np.uint8)
        mask[~valid] = MASK_NODATA
        write_geotiff(stable_mask_out, mask, transform, crs)
    progress(1.0)

    raw = (post - pre)[stable]
    after = (corrected - pre)[stable & np.isfinite(corrected)]
    return CoregisterResult(
        shift_east_m=float(shift[0]),
        shift_north_m=float(shift[1]),
        shift_up_m=float(-plane.a),
        shift_east_px=float(shift[0] / res_x),
        shift_north_px=float(shift[1] / res_y),
        horizontal_estimated=horizontal,
        tilt_east_m_per_km=float(-plane.b * 1000) if options.tilt else None,
        tilt_north_m_per_km=float(-plane.c * 1000) if options.tilt else None,
        tilt_pivot_east_m=float(transform.c + transform.a * pre.shape[1] / 2),
        tilt_pivot_north_m=float(transform.f + transform.e * pre.shape[0] / 2),
        nmad_before_m=nmad(raw),
        nmad_after_m=nmad(after),
        median_before_m=float(np.median(raw)),
        median_after_m=float(np.median(after)),
        stable_fraction=float(np.count_nonzero(stable) / max(np.count_nonzero(valid), 1)),
        iterations=iterations,
        notes=notes,
        seconds=time.perf_counter() - start,
        initial_shift_east_m=initial[0],
        initial_shift_north_m=initial[1],
        dome_m_per_m2=(-plane.d, -plane.e, -plane.f),
        dome_range_m=_dome_range(plane, dx, dy),
        rotation_deg=float(np.degrees(theta)),
    )


def _refine_rotation(
    pre: np.ndarray,
    pre_smooth: np.ndarray,
    post: np.ndarray,
    shifted: np.ndarray,
    stable: np.ndarray,
    transform: Affine,
    crs: rasterio.crs.CRS,
    shift: tuple[float, float],
    plane: _Plane,
    dx: np.ndarray,
    dy: np.ndarray,
    options: CoregisterOptions,
) -> tuple[tuple[float, float], float, np.ndarray, _Plane]:
    """Shift, rotation, moved post and plane after the linearised surface match (module
    doc); the input estimate (`shifted`: post moved by `shift`) unchanged when the
    rotation does not lower the spread."""
    gy, gx = np.gradient(pre_smooth.astype(np.float64), transform.e, transform.a)
    rows, cols = np.nonzero(stable & np.isfinite(gx) & np.isfinite(gy))
    if rows.size > options.subsample:
        pick = np.random.default_rng(options.seed).choice(
            rows.size, options.subsample, replace=False
        )
        rows, cols = rows[np.sort(pick)], cols[np.sort(pick)]
    if rows.size < options.min_stable_pixels:
        return shift, 0.0, shifted, plane
    x, y = dx[0, cols].astype(np.float64), dy[rows, 0].astype(np.float64)
    ex, ey = gx[rows, cols], gy[rows, cols]
    columns = [ex, ey, ex * -y + ey * x, np.ones(rows.size)]
    if options.tilt:
        columns += [x, y]
        if options.dome:
            columns += [x * x, y * y, x * y]
    design = np.column_stack(columns)

    def spread(moved: np.ndarray, fitted: _Plane) -> float:
        dh = (moved - pre - fitted.evaluate(dx, dy))[stable]
        return nmad(dh[np.isfinite(dh)])

    best = (shift, 0.0, shifted, plane)
    best_spread = spread(shifted, plane)
    moved, current_shift, theta = shifted, shift, 0.0
    for _ in range(max(options.rotation_iterations, 1)):
        values = (moved - pre)[rows, cols].astype(np.float64)
        ok = np.isfinite(values)
        keep = ok.copy()
        coef = np.zeros(design.shape[1])
        for _ in range(2):  # second pass without the residual outliers of the first
            coef = np.linalg.lstsq(design[keep], values[keep], rcond=None)[0]
            residual = np.where(ok, values - design @ coef, np.inf)
            keep = ok & (np.abs(residual) <= 3.0 * max(nmad(residual[ok]), 1e-6))
        # Moving post on by a small motion m changes dh by -grad . m: the dh left is
        # grad . m + plane, so the fitted motion is what is still to apply.
        current_shift = (current_shift[0] + coef[0], current_shift[1] + coef[1])
        theta += coef[2]
        moved = _apply_motion(post, transform, crs, current_shift, theta)
        fitted = _fit_plane(moved - pre, stable, dx, dy, options)
        candidate_spread = spread(moved, fitted)
        if candidate_spread >= best_spread:
            break
        best, best_spread = (current_shift, theta, moved, fitted), candidate_spread
        # The motion's largest displacement over the grid, in pixels: done below 0.01.
        radius = float(np.hypot(np.abs(dx).max(), np.abs(dy).max()))
        step_px = (np.hypot(coef[0], coef[1]) + abs(coef[2]) * radius) / abs(transform.a)
        if step_px < 0.01:
            break
    return best


def _dome_range(plane: _Plane, dx: np.ndarray, dy: np.ndarray) -> float:
    if not (plane.d or plane.e or plane.f):
        return 0.0
    quadratic = _Plane(0.0, 0.0, 0.0, plane.d, plane.e, plane.f).evaluate(dx, dy)
    return float(quadratic.max() - quadratic.min())


def _initial_shift(
    pre: np.ndarray,
    post: np.ndarray,
    transform: Affine,
    crs: rasterio.crs.CRS,
    options: CoregisterOptions,
) -> tuple[tuple[float, float], np.ndarray]:
    """The phase-correlation shift and post moved by it, when it is over a pixel and the
    DSMs agree better with it (a smaller NMAD of post - pre) than without; else no shift
    and post as it is."""
    none = ((0.0, 0.0), post)
    if not options.coarse_shift:
        return none
    res_x, res_y = abs(transform.a), abs(transform.e)
    found = coarse_shift(pre, post, res_x, res_y)
    if not found.used or np.hypot(found.east_m / res_x, found.north_m / res_y) < 1.0:
        return none
    shift = (found.east_m, found.north_m)
    moved = _apply_shift(post, transform, crs, shift)

    def spread(dh: np.ndarray) -> float:
        return nmad(dh[np.isfinite(dh)])

    return (shift, moved) if spread(moved - pre) < spread(post - pre) else none


def _centred_coordinates(
    transform: Affine, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Map x and y of pixel centres relative to the grid centre (broadcastable arrays)."""
    rows, cols = shape
    dx = (np.arange(cols) + 0.5 - cols / 2) * transform.a
    dy = (np.arange(rows) + 0.5 - rows / 2) * transform.e
    return dx[np.newaxis, :], dy[:, np.newaxis]


def _has_horizontal_information(
    pre: np.ndarray, valid: np.ndarray, res_x: float, res_y: float, options: CoregisterOptions
) -> bool:
    # Smooth first so that pixel noise on flat ground does not read as slope.
    filled = np.where(np.isfinite(pre), pre, np.nanmedian(pre))
    smooth = ndimage.gaussian_filter(filled.astype(np.float64), sigma=2.0)
    grad_y, grad_x = np.gradient(smooth, res_y, res_x)
    slope = np.degrees(np.arctan(np.hypot(grad_x, grad_y)))
    interior = ndimage.binary_erosion(valid, iterations=3)
    if not interior.any():
        return False
    return float(np.mean(slope[interior] >= options.min_slope_deg)) >= options.min_sloped_fraction


def _smooth(array: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian smoothing that ignores NaN; pixels near nodata become NaN."""
    if sigma_px <= 0:
        return array
    valid = np.isfinite(array)
    values = ndimage.gaussian_filter(np.where(valid, array, 0.0).astype(np.float64), sigma_px)
    weight = ndimage.gaussian_filter(valid.astype(np.float64), sigma_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = values / weight
    smooth[weight < 0.99] = np.nan
    return smooth.astype(np.float32)


def _nuth_kaab(
    pre: np.ndarray,
    post: np.ndarray,
    stable: np.ndarray,
    transform: Affine,
    crs: rasterio.crs.CRS,
    options: CoregisterOptions,
) -> tuple[float, float]:
    """Horizontal correction (east, north) in metres to apply to post."""
    try:
        return nuth_kaab_shift(
            pre,
            post,
            stable,
            (abs(transform.a), abs(transform.e)),
            max_iterations=options.nuth_kaab_max_iterations,
            tolerance_px=options.nuth_kaab_tolerance_px,
            subsample=options.subsample,
            seed=options.seed,
        )
    except NuthKaabError as exc:
        raise InputError(f"co-registration failed to converge ({exc})") from exc


def _apply_shift(
    post: np.ndarray, transform: Affine, crs: rasterio.crs.CRS, shift: tuple[float, float]
) -> np.ndarray:
    """post(x - east, y - north) on the same grid, by bilinear resampling."""
    return _apply_motion(post, transform, crs, shift, 0.0)


def _apply_motion(
    post: np.ndarray,
    transform: Affine,
    crs: rasterio.crs.CRS,
    shift: tuple[float, float],
    theta: float,
) -> np.ndarray:
    """post with each feature at q moved to R(theta) (q - c) + c + shift, c the grid
    centre, on the same grid by bilinear resampling."""
    if shift == (0.0, 0.0) and theta == 0.0:
        return post.copy()
    rows, cols = post.shape
    cx, cy = transform * (cols / 2, rows / 2)
    rotate = Affine.rotation(np.degrees(theta), pivot=(cx, cy))
    moved = Affine.translation(shift[0], shift[1]) @ rotate @ transform
    return warp_elevation(post, moved, crs, transform, crs, post.shape)


def _fit_plane(
    dh: np.ndarray, stable: np.ndarray, dx: np.ndarray, dy: np.ndarray, options: CoregisterOptions
) -> _Plane:
    """Robust fit of dh on stable terrain: the median, or a plane when `tilt` is on (with
    quadratic terms when `dome` is on too)."""
    rows, cols = np.nonzero(stable & np.isfinite(dh))
    if rows.size > options.subsample:
        pick = np.random.default_rng(options.seed).choice(
            rows.size, options.subsample, replace=False
        )
        pick.sort()
        rows, cols = rows[pick], cols[pick]
    values = dh[rows, cols].astype(np.float64)
    if not options.tilt:
        return _Plane(float(np.median(values)))
    x, y = dx[0, cols], dy[rows, 0]
    columns = [np.ones(rows.size), x, y]
    if options.dome:
        columns += [x * x, y * y, x * y]
    design = np.column_stack(columns)
    keep = np.ones(rows.size, dtype=bool)
    coef = np.zeros(design.shape[1])
    for _ in range(2):  # second pass without the residual outliers of the first
        coef = np.linalg.lstsq(design[keep], values[keep], rcond=None)[0]
        residual = values - design @ coef
        keep = np.abs(residual - np.median(residual)) <= 3.0 * max(nmad(residual), 1e-6)
    return _Plane(*(float(c) for c in coef))


def _stable_terrain(
    dh: np.ndarray, valid: np.ndarray, stable: np.ndarray, options: CoregisterOptions
) -> np.ndarray:
    values = dh[stable & valid]
    median, spread = float(np.median(values)), nmad(values)
    with np.errstate(invalid="ignore"):
        unstable = (np.abs(dh - median) > options.outlier_nmad_factor * spread) | (
            np.abs(dh) > options.max_abs_change_m
        )
    unstable &= valid
    # Ignore isolated noise pixels; grow real change areas to cover their fringes.
    unstable = ndimage.binary_opening(unstable, structure=np.ones((2, 2), dtype=bool))
    if options.unstable_buffer_px > 0:
        unstable = ndimage.binary_dilation(unstable, iterations=options.unstable_buffer_px)
    return valid & ~unstable
