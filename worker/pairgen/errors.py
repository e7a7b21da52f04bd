"""Observation error models: what two photogrammetric surveys and their registration add.

`draw_errors` draws every error of a pair (fields, masks, offsets) from the pair's
error stream and the grid alone, never from the DSMs: a pair and its no-change twin
then get the same errors, draw for draw. `apply_errors` puts them on the two true DSMs.

Per survey, independently: white noise, spatially correlated noise, doming, tilt, steps
between flight strips, outlier spikes and holes (NaN, then inpainted or left). On the
post survey only: the registration error (a horizontal shift and a rotation applied to
the whole post DSM by cubic-spline resampling, plus a vertical offset) and a coarser
resolution (block-averaged, then interpolated back onto the one grid).

All amplitudes are in multiples of `sigma`, the per-survey noise level the generator
draws for the pair, so one number sets how hard a pair is.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from worker.pairgen.fields import gaussian_field, loguniform, power_law_field

ERRORS = (
    "white",
    "correlated",
    "doming",
    "tilt",
    "strips",
    "holes",
    "outliers",
    "shift",
    "rotation",
    "resolution",
)
DEFAULTS: dict[str, Any] = {
    "shift_px": (0.2, 3.0),  # horizontal registration error of the post, pixels
    "shift_angle_deg": (0.0, 360.0),
    "vertical_m": 0.5,  # vertical offset of the post within +-this
    "rotation_deg": 0.2,  # rotation of the post within +-this
    "resolution_factor": (2, 3),
    "correlation_m": (None, 30.0),  # None: 3 pixels
    "hole_fraction": (0.005, 0.03),
    "holes_nan_chance": 0.3,  # a survey's holes are left NaN rather than filled
    "outlier_fraction": (1e-4, 1e-3),
}


@dataclass
class SurveyErrors:
    """The errors of one survey, drawn; `additive` holds the sum of the smooth ones."""

    additive: np.ndarray
    outliers: np.ndarray  # value added (0 where none)
    holes: np.ndarray  # bool
    holes_fill: bool
    hole_scale_px: float


@dataclass
class ErrorPlan:
    pre: SurveyErrors
    post: SurveyErrors
    shift_px: tuple[float, float] = (0.0, 0.0)  # (rows, cols) the post is moved by
    vertical_m: float = 0.0
    rotation_deg: float = 0.0
    resolution_factor: int = 1
    description: dict[str, Any] = field(default_factory=dict)


def _survey(
    names: Sequence[str],
    shape: tuple[int, int],
    pixel_size: float,
    sigma: float,
    rng: np.random.Generator,
    p: Mapping[str, Any],
    info: dict[str, Any],
) -> SurveyErrors:
    """One survey's draws, in a fixed order whatever `names` holds (stable streams)."""
    rows, cols = shape
    extent = max(shape) * pixel_size
    add = np.zeros(shape)
    # White and correlated noise share sigma^2 when both are there.
    white_share = rng.uniform(0.3, 0.7) if "white" in names and "correlated" in names else 1.0
    if "white" in names:
        s = sigma * np.sqrt(white_share)
        add += s * rng.standard_normal(shape)
        info["white_sigma_m"] = s
    if "correlated" in names:
        s = sigma * np.sqrt(1 - white_share) if "white" in names else sigma
        lo, hi = p["correlation_m"]
        lo = 3 * pixel_size if lo is None else lo
        corr = loguniform(rng, lo, max(min(hi, extent / 4), lo * 1.01))
        if rng.uniform() < 0.5:
            noise = gaussian_field(shape, pixel_size, rng, corr)
            info["correlated"] = {"kind": "gaussian", "range_m": corr, "sigma_m": s}
        else:
            beta = rng.uniform(2.0, 3.0)
            noise = power_law_field(shape, pixel_size, rng, beta, outer_m=corr)
            info["correlated"] = {"kind": "power-law", "range_m": corr, "beta": beta, "sigma_m": s}
        add += s * noise
    r = (np.arange(rows)[:, None] - (rows - 1) / 2) / max(shape)
    c = (np.arange(cols)[None, :] - (cols - 1) / 2) / max(shape)
    if "doming" in names:
        # A bowl (or dome) from a slightly wrong lens model: amplitude 0.1-1 x 3 sigma.
        amp = rng.uniform(0.1, 1.0) * 3 * sigma * rng.choice([-1.0, 1.0])
        cr, cc = rng.uniform(-0.2, 0.2, size=2)
        bowl = (r - cr) ** 2 + (c - cc) ** 2
        add += amp * (bowl / bowl.max() - bowl.mean() / bowl.max())
        info["doming_m"] = amp
    if "tilt" in names:
        rise = rng.uniform(0.5, 3.0) * sigma
        angle = rng.uniform(0, 2 * np.pi)
        add += rise * (r * np.cos(angle) + c * np.sin(angle))
        info["tilt_m"] = rise
    if "strips" in names:
        # Flight strips of one width, offset alternately up and down by 0.25-1.5 sigma:
        # steps of 0.5-3 sigma between neighbours that do not add up across the block.
        width = rng.uniform(0.15, 0.4) * extent
        angle = rng.uniform(0, np.pi)
        across = (r * np.sin(angle) + c * np.cos(angle)) * extent
        index = np.floor((across - across.min()) / width).astype(int)
        sign = rng.choice([-1.0, 1.0]) * (-1.0) ** np.arange(16)
        offsets = rng.uniform(0.25, 1.5, size=16) * sigma * sign
        strip = offsets[np.clip(index, 0, 15)]
        add += strip - strip.mean()
        steps = np.abs(np.diff(offsets)) / sigma
        info["strips"] = {"width_m": width, "mean_step_sigma": float(steps.mean())}
    outliers = np.zeros(shape)
    if "outliers" in names:
        n = max(1, int(rng.uniform(*p["outlier_fraction"]) * rows * cols))
        at_r = rng.integers(0, rows - 1, size=n)
        at_c = rng.integers(0, cols - 1, size=n)
        values = rng.uniform(5.0, 30.0, size=n) * sigma * rng.choice([-1.0, 1.0], size=n)
        blob = rng.uniform(size=n) < 0.5  # half are 2 x 2 blobs, half single pixels
        outliers[at_r, at_c] = values
        for dr, dc in ((0, 1), (1, 0), (1, 1)):
            outliers[at_r[blob] + dr, at_c[blob] + dc] = values[blob]
        info["outliers"] = n
    holes = np.zeros(shape, dtype=bool)
    scale = 0.0
    fill = True
    if "holes" in names:
        fraction = rng.uniform(*p["hole_fraction"])
        scale = max(3.0, rng.uniform(1.0, 5.0) / pixel_size)
        scale = min(scale, max(shape) / 20)
        blobs = gaussian_field(shape, pixel_size, rng, scale * pixel_size)
        holes = blobs > np.quantile(blobs, 1 - fraction)
        fill = bool(rng.uniform() >= p["holes_nan_chance"])
        info["holes"] = {"fraction": fraction, "scale_px": scale, "filled": fill}
    return SurveyErrors(add, outliers, holes, fill, scale)


def draw_errors(
    names: Sequence[str],
    shape: tuple[int, int],
    pixel_size: float,
    sigma: float,
    rng: np.random.Generator,
    params: Mapping[str, Any] | None = None,
) -> ErrorPlan:
    """Every error of a pair, drawn from `rng` and the grid only (see the module doc)."""
    unknown = set(names) - set(ERRORS)
    if unknown:
        raise ValueError(f"unknown error models: {sorted(unknown)}")
    p = {**DEFAULTS, **dict(params or {})}
    pre_info: dict[str, Any] = {}
    post_info: dict[str, Any] = {}
    pre = _survey(names, shape, pixel_size, sigma, rng, p, pre_info)
    post = _survey(names, shape, pixel_size, sigma, rng, p, post_info)
    plan = ErrorPlan(pre, post, description={"sigma_m": sigma, "pre": pre_info, "post": post_info})
    if "shift" in names:
        magnitude = rng.uniform(*p["shift_px"])
        angle = np.radians(rng.uniform(*p["shift_angle_deg"]))
        plan.shift_px = (float(magnitude * np.sin(angle)), float(magnitude * np.cos(angle)))
        plan.vertical_m = float(rng.uniform(-p["vertical_m"], p["vertical_m"]))
        plan.description["shift"] = {
            "rows_px": plan.shift_px[0],
            "cols_px": plan.shift_px[1],
            "vertical_m": plan.vertical_m,
        }
    if "rotation" in names:
        plan.rotation_deg = float(rng.uniform(-p["rotation_deg"], p["rotation_deg"]))
        plan.description["rotation_deg"] = plan.rotation_deg
    if "resolution" in names:
        plan.resolution_factor = int(rng.choice(p["resolution_factor"]))
        plan.description["resolution_factor"] = plan.resolution_factor
    return plan


def register(dsm: np.ndarray, shift_px: tuple[float, float], rotation_deg: float) -> np.ndarray:
    """`dsm` moved by shift_px (rows, cols) and rotated about the grid centre.

    A feature at (r, c) of `dsm` lands at about (r, c) + shift_px: the output samples
    the input at the inverse position, by cubic spline.
    """
    if shift_px == (0.0, 0.0) and rotation_deg == 0.0:
        return dsm.copy()
    rows, cols = dsm.shape
    rr, cc = np.mgrid[0:rows, 0:cols].astype(float)
    r0, c0 = (rows - 1) / 2, (cols - 1) / 2
    theta = np.radians(rotation_deg)
    dr, dc = rr - r0 - shift_px[0], cc - c0 - shift_px[1]
    src_r = r0 + dr * np.cos(theta) - dc * np.sin(theta)
    src_c = c0 + dr * np.sin(theta) + dc * np.cos(theta)
    return ndimage.map_coordinates(dsm, [src_r, src_c], order=3, mode="nearest")


def coarsen(dsm: np.ndarray, factor: int) -> np.ndarray:
    """Block mean over factor x factor, interpolated back (bilinear) onto the grid."""
    if factor <= 1:
        return dsm
    rows, cols = dsm.shape
    padded = np.pad(dsm, ((0, (-rows) % factor), (0, (-cols) % factor)), mode="edge")
    coarse = padded.reshape(
        padded.shape[0] // factor, factor, padded.shape[1] // factor, factor
    ).mean(axis=(1, 3))
    rr = (np.arange(rows) - (factor - 1) / 2) / factor
    cc = (np.arange(cols) - (factor - 1) / 2) / factor
    grid = np.meshgrid(rr, cc, indexing="ij")
    return ndimage.map_coordinates(coarse, grid, order=1, mode="nearest")


def fill_holes(dsm: np.ndarray, holes: np.ndarray, scale_px: float) -> np.ndarray:
    """Inpaint `holes`: nearest valid value, smoothed at the holes' scale.

    What a photogrammetry package does to a gap: a plausible, too-smooth surface.
    """
    if not holes.any():
        return dsm
    _, (ir, ic) = ndimage.distance_transform_edt(holes, return_indices=True)
    nearest = dsm[ir, ic]
    smooth = ndimage.gaussian_filter(nearest, max(scale_px / 2, 1.0), mode="nearest")
    return np.where(holes, smooth, dsm)


def _finish_survey(dsm: np.ndarray, e: SurveyErrors) -> np.ndarray:
    out = dsm + e.additive + e.outliers
    if e.holes.any():
        out = fill_holes(out, e.holes, e.hole_scale_px) if e.holes_fill else out
        if not e.holes_fill:
            out = np.where(e.holes, np.nan, out)
    return out


def apply_errors(
    plan: ErrorPlan, pre_true: np.ndarray, post_true: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The observed (pre, post) DSMs: registration and resolution first, as they act on
    the whole post surface, then each survey's own noise, spikes and holes."""
    post = register(post_true, plan.shift_px, plan.rotation_deg) + plan.vertical_m
    post = coarsen(post, plan.resolution_factor)
    return _finish_survey(pre_true, plan.pre), _finish_survey(post, plan.post)
