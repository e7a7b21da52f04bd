"""Terrain models: bare-ground heights (metres, float64) on a north-up grid.

Each model takes (shape, pixel_size, rng, **params) and draws everything it needs from
`rng`. Landforms are sized in metres, not pixels: the same seed at another pixel size
is the same kind of place seen finer or coarser. Slopes are set by rescaling relief to
a target RMS gradient, which (unlike an RMS height) is what decides where a slide can
sit. Buildings are not terrain: they change between surveys, so they live in
`surfaces.urban`; the urban ground here carries the roads and the cut slope.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from worker.pairgen.fields import (
    gaussian_field,
    power_law_field,
    rms_gradient,
    smooth,
    smoothstep,
)
from worker.pairgen.real_terrain import real_relief

TerrainModel = Callable[..., np.ndarray]


def _coords_m(shape: tuple[int, int], pixel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Northing-like (down the rows) and easting-like coordinates in metres, centred."""
    rows, cols = shape
    r = (np.arange(rows) - (rows - 1) / 2.0) * pixel_size
    c = (np.arange(cols) - (cols - 1) / 2.0) * pixel_size
    return r[:, None], c[None, :]


def _plane(
    shape: tuple[int, int], pixel_size: float, slope_deg: float, azimuth: float
) -> np.ndarray:
    """A plane falling at slope_deg towards `azimuth` (radians, in row/col axes)."""
    r, c = _coords_m(shape, pixel_size)
    along = r * np.cos(azimuth) + c * np.sin(azimuth)
    return -np.tan(np.radians(slope_deg)) * along


def _with_gradient(z: np.ndarray, pixel_size: float, target: float) -> np.ndarray:
    g = rms_gradient(z, pixel_size)
    return z * (target / g) if g > 0 else z


def _micro(
    shape: tuple[int, int], pixel_size: float, rng: np.random.Generator, rms_m: float
) -> np.ndarray:
    """Decimetre-scale roughness (clods, stones, tussocks): texture at fine pixels."""
    return rms_m * power_law_field(shape, pixel_size, rng, beta=3.0, outer_m=2.0)


def _ridged(
    shape: tuple[int, int], pixel_size: float, rng: np.random.Generator, spacing_m: float
) -> np.ndarray:
    """Ridged multifractal: (1 - |n|)^2 makes sharp crests along the zero lines of n."""
    out = np.zeros(shape)
    for octave in range(3):
        scale = spacing_m / 2**octave
        n = power_law_field(shape, pixel_size, rng, beta=4.0, outer_m=scale, inner_m=scale / 10)
        out += 0.4**octave * np.clip(1.0 - np.abs(n), 0.0, None) ** 2
    return out


def _valleys(
    shape: tuple[int, int], pixel_size: float, rng: np.random.Generator, spacing_m: float
) -> np.ndarray:
    """Meandering troughs along the zero lines of a smooth field: a drainage-like net.

    Zero lines of a random field neither end nor cross, like channels of one order.
    """
    n = gaussian_field(shape, pixel_size, rng, spacing_m / 2)
    return np.exp(-((n / 0.3) ** 2))


def fractal(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    slope_deg: tuple[float, float] = (27.0, 36.0),
    relief_gradient: tuple[float, float] = (0.10, 0.16),
    roughness_m: tuple[float, float] = (0.02, 0.06),
) -> np.ndarray:
    """Hillslope: regional plane plus power-law relief; local slopes mostly 20-45°."""
    extent = max(shape) * pixel_size
    z = _plane(shape, pixel_size, rng.uniform(*slope_deg), rng.uniform(0, 2 * np.pi))
    landform = power_law_field(
        shape,
        pixel_size,
        rng,
        beta=rng.uniform(3.2, 3.8),
        outer_m=extent,
        inner_m=max(3 * pixel_size, extent / 60),
    )
    z += _with_gradient(landform, pixel_size, rng.uniform(*relief_gradient))
    z += _micro(shape, pixel_size, rng, rng.uniform(*roughness_m))
    return z + rng.uniform(150.0, 900.0)


def ridge_valley(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    tilt_deg: tuple[float, float] = (10.0, 20.0),
    relief_gradient: tuple[float, float] = (0.35, 0.55),
    roughness_m: tuple[float, float] = (0.02, 0.05),
) -> np.ndarray:
    """Ridges and valleys on a tilted flank: ridged multifractal minus a valley net."""
    extent = max(shape) * pixel_size
    spacing = extent * rng.uniform(0.4, 0.8)
    relief = _ridged(shape, pixel_size, rng, spacing)
    relief = relief / relief.std() - rng.uniform(1.2, 2.0) * _valleys(
        shape, pixel_size, rng, spacing
    )
    relief = _with_gradient(relief, pixel_size, rng.uniform(*relief_gradient))
    z = _plane(shape, pixel_size, rng.uniform(*tilt_deg), rng.uniform(0, 2 * np.pi)) + relief
    z += _micro(shape, pixel_size, rng, rng.uniform(*roughness_m))
    return z + rng.uniform(200.0, 1200.0)


def terraced(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    slope_deg: tuple[float, float] = (12.0, 22.0),
    riser_m: tuple[float, float] = (1.0, 3.0),
    riser_width_m: tuple[float, float] = (0.4, 1.2),
    roughness_m: tuple[float, float] = (0.01, 0.03),
) -> np.ndarray:
    """Stepped terraces on a slope: near-flat treads and steep risers of 1-3 m.

    Terraces follow the contours of a gently undulating slope, so their edges curve.
    """
    extent = max(shape) * pixel_size
    theta = rng.uniform(*slope_deg)
    base = _plane(shape, pixel_size, theta, rng.uniform(0, 2 * np.pi))
    base += _with_gradient(
        power_law_field(shape, pixel_size, rng, 3.8, outer_m=extent, inner_m=extent / 20),
        pixel_size,
        0.05,
    )
    riser = rng.uniform(*riser_m)
    spacing = riser / np.tan(np.radians(theta))  # horizontal distance between risers
    fraction = float(np.clip(rng.uniform(*riser_width_m) / spacing, 0.05, 0.5))
    t = base / riser
    step = np.floor(t)
    within = t - step
    # Treads keep a tenth of the slope (drainage); the rest of each step is the riser.
    tread_tilt = rng.uniform(0.05, 0.15)
    rise = smoothstep((within - (1.0 - fraction)) / fraction)
    z = riser * (step + (1.0 - tread_tilt) * rise + tread_tilt * within)
    z += _micro(shape, pixel_size, rng, rng.uniform(*roughness_m))
    return z + rng.uniform(50.0, 600.0)


def agricultural(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    tilt_deg: tuple[float, float] = (3.0, 7.0),
    roughness_m: tuple[float, float] = (0.005, 0.015),
) -> np.ndarray:
    """Smooth gentle fields (< 10°) with parcel edges, a ditch and plough furrows.

    Parcels are strips a few tens of metres wide; at 2-5 cm pixels the raster sees one or
    two of them, so one parcel edge is put inside the raster on purpose.
    """
    extent = max(shape) * pixel_size
    azimuth = rng.uniform(0, 2 * np.pi)
    z = _plane(shape, pixel_size, rng.uniform(*tilt_deg), azimuth)
    z += _with_gradient(
        power_law_field(shape, pixel_size, rng, 4.0, outer_m=4 * extent, inner_m=extent / 8),
        pixel_size,
        0.02,
    )
    r, c = _coords_m(shape, pixel_size)
    strip_dir = rng.uniform(0, np.pi)
    across = r * np.cos(strip_dir) + c * np.sin(strip_dir)
    width = rng.uniform(0.6, 1.5) * extent
    # One boundary at a drawn place inside the raster, the next a parcel width away.
    first = rng.uniform(-0.3, 0.3) * extent
    parcel = np.floor((across - first) / width)
    offsets = rng.uniform(-0.15, 0.15, size=8)
    level = offsets[(parcel.astype(int) + 4) % 8]
    bank = rng.uniform(0.3, 0.8)  # m: the step between parcels is a short bank
    z += smooth(level + np.zeros(shape), bank / pixel_size / 2)
    # Ditch along the drawn boundary: V-shaped, 0.2-0.6 m deep, 0.8-2 m wide.
    depth, half_width = rng.uniform(0.2, 0.6), rng.uniform(0.4, 1.0)
    z -= depth * np.clip(1.0 - np.abs(across - first) / half_width, 0.0, None) ** 1.5
    # Furrows along the strips, different phase per parcel.
    period, amplitude = rng.uniform(0.3, 0.9), rng.uniform(0.01, 0.05)
    phases = rng.uniform(0, 2 * np.pi, size=8)
    furrow = np.sin(2 * np.pi * across / period + phases[(parcel.astype(int) + 4) % 8])
    z += amplitude * furrow * smoothstep(np.abs(across - first) / (2 * half_width))
    z += _micro(shape, pixel_size, rng, rng.uniform(*roughness_m))
    return z + rng.uniform(20.0, 300.0)


def urban(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    tilt_deg: tuple[float, float] = (0.5, 3.0),
    cut_height_m: tuple[float, float] = (15.0, 35.0),
    cut_slope_deg: tuple[float, float] = (40.0, 55.0),
    features: dict[str, np.ndarray] | None = None,
) -> np.ndarray:
    """Gentle town ground with graded roads, and a steep cut slope along one side.

    The cut slope (a hill cut back for the town) is where rockfalls and translational
    slides can happen; buildings are added by `surfaces.urban` on the flat part, so
    `features` receives the road mask and the hill (face and top) mask.
    """
    extent = max(shape) * pixel_size
    z = _plane(shape, pixel_size, rng.uniform(*tilt_deg), rng.uniform(0, 2 * np.pi))
    z += _with_gradient(
        power_law_field(shape, pixel_size, rng, 4.0, outer_m=2 * extent, inner_m=extent / 10),
        pixel_size,
        0.02,
    )
    # Roads: graded flat across (the ground smoothed hard) and sunk 0.15 m below kerbs.
    r, c = _coords_m(shape, pixel_size)
    road = np.zeros(shape, dtype=bool)
    for axis_coord, n in ((r, rng.integers(1, 3)), (c, rng.integers(1, 3))):
        for _ in range(int(n)):
            centre = rng.uniform(-0.4, 0.4) * extent
            half = rng.uniform(3.0, 6.0)
            road |= np.broadcast_to(np.abs(axis_coord - centre) < half, shape)
    graded = smooth(z, 8.0 / pixel_size) - 0.15
    z = np.where(road, graded, z)
    # Cut slope: the ground rises by H over a face of H / tan(angle) along one side.
    side = int(rng.integers(4))
    dist = [r - r.min(), r.max() - r, c - c.min(), c.max() - c][side]
    dist = np.broadcast_to(dist, shape)
    height = rng.uniform(*cut_height_m)
    face = height / np.tan(np.radians(rng.uniform(*cut_slope_deg)))
    foot = rng.uniform(0.3, 0.4) * extent
    foot = np.clip(foot, face + 10.0, None)
    wiggle = 0.1 * face * gaussian_field(shape, pixel_size, rng, extent / 6)
    rise = np.clip((foot + wiggle - dist) / face, 0.0, 1.0)
    # Rounded crest and foot (a few metres), a straight face between.
    rise = smooth(rise, min(2.0, 0.15 * face) / pixel_size)
    hill = (
        rng.uniform(0.05, 0.15)
        * height
        * power_law_field(shape, pixel_size, rng, 3.5, outer_m=extent / 3, inner_m=2.0)
    )
    z += height * rise + hill * rise
    z += _micro(shape, pixel_size, rng, 0.02)
    if features is not None:
        features["road"] = road.copy()
        features["hill"] = rise > 0.01
    return z + rng.uniform(10.0, 200.0)


def mountain(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    slope_deg: tuple[float, float] = (34.0, 40.0),
    relief_gradient: tuple[float, float] = (0.18, 0.28),
    roughness_m: tuple[float, float] = (0.05, 0.2),
) -> np.ndarray:
    """Steep mountain flank (30-50°), hundreds of metres of relief, gullies and spurs."""
    extent = max(shape) * pixel_size
    z = _plane(shape, pixel_size, rng.uniform(*slope_deg), rng.uniform(0, 2 * np.pi))
    spacing = extent * rng.uniform(0.3, 0.6)
    relief = _ridged(shape, pixel_size, rng, spacing)
    relief = relief / relief.std() - rng.uniform(0.5, 1.0) * _valleys(
        shape, pixel_size, rng, spacing
    )
    z += _with_gradient(relief, pixel_size, rng.uniform(*relief_gradient))
    z += _micro(shape, pixel_size, rng, rng.uniform(*roughness_m))
    return z + rng.uniform(800.0, 2200.0)


TERRAINS: dict[str, TerrainModel] = {
    "fractal": fractal,
    "real": real_relief,
    "ridge-valley": ridge_valley,
    "terraced": terraced,
    "agricultural": agricultural,
    "urban": urban,
    "mountain": mountain,
}


# Models that report what they drew (roads, ...) for the surface models to respect.
REPORTING = ("urban",)


def make_terrain(
    name: str,
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    params: Mapping[str, Any] | None = None,
    features: dict[str, np.ndarray] | None = None,
) -> np.ndarray:
    """Heights of terrain model `name`; `features` receives its masks where it has any."""
    extra: dict[str, Any] = {"features": features} if name in REPORTING else {}
    return TERRAINS[name](shape, pixel_size, rng, **dict(params or {}), **extra)
