"""Synthetic pre/post DSM pairs with known truth, for tests and benchmarks.

The terrain is an analytic function of metric coordinates (a regional slope plus seeded
sinusoids and gaussian hills), so the post DSM can be evaluated exactly at shifted
coordinates instead of being resampled. A planted landslide removes material from an
elliptical bowl upslope and deposits it in an elliptical lobe downslope.

Conventions:
- `shift_m = (east, north, up)` is the displacement of the post survey relative to the
  pre survey: post(x, y) = surface(x - east, y - north) + up. Co-registration should find
  the opposite correction.
- Truth (mask, area, volumes) describes the change in the pre survey's frame. For a
  geographic CRS the area and volumes are computed on a metric grid of the same nominal
  pixel size in the local UTM zone, which is where the surface is defined.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import rasterio
from pyproj import CRS, Transformer
from rasterio.transform import Affine, from_origin

from worker.pipeline.geo import utm_crs_for_lonlat
from worker.pipeline.raster_io import write_geotiff

# Below this |dh| (m) a pixel counts as unchanged in the truth.
TRUTH_EPSILON_M = 1e-3
# Exponent of the slide profile 1 - r**p: high values give a flat floor and steep walls,
# so the changed region has a sharp edge like a real scarp.
_PROFILE_POWER = 12
_METRES_PER_DEGREE_LAT = 110_574.0
_METRES_PER_DEGREE_LON_EQUATOR = 111_320.0


@dataclass(frozen=True)
class SlideSpec:
    """A planted landslide, in fractions of the raster extent and metres.

    The depletion bowl (semi-axes along/across slope) sits upslope of `centre_frac`,
    the deposit lobe downslope; the deposit height is set so that the volumes match.
    """

    centre_frac: tuple[float, float] = (0.5, 0.5)  # (column, row) fraction of the extent
    depletion_semi_axes_frac: tuple[float, float] = (0.08, 0.06)
    deposit_semi_axes_frac: tuple[float, float] = (0.10, 0.07)
    depth_m: float = 2.5
    gap_px: float = 1.0  # gap between bowl and lobe along the slope, in pixels


@dataclass
class SlideTruth:
    """What changed between the two surveys."""

    mask: np.ndarray  # bool, on the raster grid: |change| > TRUTH_EPSILON_M
    area_m2: float
    volume_loss_m3: float
    volume_gain_m3: float


@dataclass
class DsmPair:
    """Two DSM arrays on the same grid (NaN = nodata) with their georeference and truth."""

    pre: np.ndarray
    post: np.ndarray
    transform: Affine
    crs: str
    pixel_size_m: float
    shift_m: tuple[float, float, float]
    tilt_m_per_km: tuple[float, float]
    truth: SlideTruth | None


class DsmPairPaths(NamedTuple):
    pre: Path
    post: Path


@dataclass(frozen=True)
class _Terrain:
    """Seeded analytic surface z(u, v) in local metric coordinates (u east, v north)."""

    base_m: float
    plane_gradient: tuple[float, float]
    waves: tuple[tuple[float, float, float, float], ...]  # amplitude, kx, ky, phase
    hills: tuple[tuple[float, float, float, float], ...]  # height, u0, v0, sigma
    flat: bool

    @classmethod
    def random(cls, rng: np.random.Generator, extent_m: float, flat: bool) -> _Terrain:
        direction = rng.uniform(0, 2 * math.pi)
        gradient = 0.0 if flat else 0.15
        waves = []
        for _ in range(4):
            wavelength = rng.uniform(extent_m / 4, extent_m / 1.5)
            slope = rng.uniform(0.15, 0.25)
            phi = rng.uniform(0, 2 * math.pi)
            k = 2 * math.pi / wavelength
            phase = rng.uniform(0, 2 * math.pi)
            waves.append((slope / k, k * math.cos(phi), k * math.sin(phi), phase))
        hills = []
        for _ in range(3):
            sigma = rng.uniform(extent_m / 12, extent_m / 6)
            height = rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 0.5) * sigma
            u0, v0 = rng.uniform(-extent_m / 2, extent_m / 2, size=2)
            hills.append((height, u0, v0, sigma))
        return cls(
            base_m=500.0,
            plane_gradient=(gradient * math.cos(direction), gradient * math.sin(direction)),
            waves=tuple(waves),
            hills=tuple(hills),
            flat=flat,
        )

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        z = np.full(np.broadcast_shapes(u.shape, v.shape), self.base_m)
        if self.flat:
            return z
        z = z + self.plane_gradient[0] * u + self.plane_gradient[1] * v
        for amp, kx, ky, phase in self.waves:
            z += amp * np.sin(kx * u + ky * v + phase)
        for height, u0, v0, sigma in self.hills:
            z += height * np.exp(-((u - u0) ** 2 + (v - v0) ** 2) / (2 * sigma**2))
        return z

    def gradient(self, u: float, v: float, step: float = 0.5) -> tuple[float, float]:
        uu = np.array([u + step, u - step, u, u])
        vv = np.array([v, v, v + step, v - step])
        z = self(uu, vv)
        return float(z[0] - z[1]) / (2 * step), float(z[2] - z[3]) / (2 * step)


@dataclass(frozen=True)
class _Slide:
    """Depletion bowl and deposit lobe: dz(u, v) with compact support."""

    depletion: tuple[float, float, float, float, float]  # u0, v0, a, b, amplitude (<0)
    deposit: tuple[float, float, float, float, float]
    direction: tuple[float, float]  # unit vector downslope

    @classmethod
    def plant(
        cls,
        spec: SlideSpec,
        terrain: _Terrain,
        centre: tuple[float, float],
        extent_m: float,
        pixel_size_m: float,
    ) -> _Slide:
        gx, gy = terrain.gradient(*centre)
        norm = math.hypot(gx, gy)
        # Downslope = minus the gradient; on flat terrain pick east.
        direction = (-gx / norm, -gy / norm) if norm > 1e-6 else (1.0, 0.0)
        ad, bd = (f * extent_m for f in spec.depletion_semi_axes_frac)
        ag, bg = (f * extent_m for f in spec.deposit_semi_axes_frac)
        half_gap = spec.gap_px * pixel_size_m / 2
        cu, cv = centre
        du, dv = direction
        depletion = (cu - du * (ad + half_gap), cv - dv * (ad + half_gap), ad, bd, -spec.depth_m)
        # Same profile shape, so the volumes scale with amplitude * a * b.
        height = spec.depth_m * ad * bd / (ag * bg)
        deposit = (cu + du * (ag + half_gap), cv + dv * (ag + half_gap), ag, bg, height)
        return cls(depletion=depletion, deposit=deposit, direction=direction)

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        du, dv = self.direction
        dz = np.zeros(np.broadcast_shapes(u.shape, v.shape))
        for u0, v0, a, b, amplitude in (self.depletion, self.deposit):
            along = (u - u0) * du + (v - v0) * dv
            across = -(u - u0) * dv + (v - v0) * du
            r2 = (along / a) ** 2 + (across / b) ** 2
            inside = r2 < 1.0
            dz[inside] += amplitude * (1.0 - r2[inside] ** (_PROFILE_POWER / 2))
        return dz


def make_dsm_pair(
    shape: tuple[int, int] = (400, 400),
    pixel_size_m: float = 1.0,
    shift_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    slide: bool | SlideSpec = True,
    noise_m: float = 0.05,
    seed: int = 0,
    crs: str = "EPSG:32632",
    origin: tuple[float, float] | None = None,
    terrain: str = "varied",
    tilt_m_per_km: tuple[float, float] = (0.0, 0.0),
) -> DsmPair:
    """Build a seeded pre/post DSM pair with a known shift and optional landslide.

    `origin` is the upper-left corner in CRS units (default: 500000 E, 5100000 N for a
    projected CRS, 9.0 E 46.0 N for a geographic one). `terrain` is "varied" (slopes of
    roughly 10-40 degrees with all aspects) or "flat" (no horizontal information).
    `tilt_m_per_km` (east, north) adds a plane through the raster centre to the post DSM,
    like a georeferencing tilt.
    """
    if terrain not in ("varied", "flat"):
        raise ValueError(f"terrain must be 'varied' or 'flat', not {terrain!r}")
    rows, cols = shape
    rng = np.random.default_rng(seed)
    crs_obj = CRS.from_user_input(crs)
    extent_m = max(rows, cols) * pixel_size_m

    if crs_obj.is_geographic:
        lon0, lat0 = origin or (9.0, 46.0)
        dlat = pixel_size_m / _METRES_PER_DEGREE_LAT
        lat_c = lat0 - rows * dlat / 2
        dlon = pixel_size_m / (_METRES_PER_DEGREE_LON_EQUATOR * math.cos(math.radians(lat_c)))
        transform = from_origin(lon0, lat0, dlon, dlat)
        lon_c = lon0 + cols * dlon / 2
        to_metric = Transformer.from_crs(crs_obj, utm_crs_for_lonlat(lon_c, lat_c), always_xy=True)
        xs, ys = _pixel_centres(transform, rows, cols)
        x, y = to_metric.transform(xs, ys)
        xc, yc = to_metric.transform(lon_c, lat_c)
    else:
        x0, y0 = origin or (500_000.0, 5_100_000.0)
        transform = from_origin(x0, y0, pixel_size_m, pixel_size_m)
        x, y = _pixel_centres(transform, rows, cols)
        xc, yc = x0 + cols * pixel_size_m / 2, y0 - rows * pixel_size_m / 2
    u, v = x - xc, y - yc

    surface = _Terrain.random(rng, extent_m, flat=terrain == "flat")
    spec = SlideSpec() if slide is True else slide or None
    planted = None
    if spec is not None:
        fc, fr = spec.centre_frac
        centre = ((fc - 0.5) * cols * pixel_size_m, (0.5 - fr) * rows * pixel_size_m)
        planted = _Slide.plant(spec, surface, centre, extent_m, pixel_size_m)

    east, north, up = shift_m
    pre = surface(u, v)
    post = surface(u - east, v - north) + up
    post += (tilt_m_per_km[0] * u + tilt_m_per_km[1] * v) / 1000.0
    truth = None
    if planted is not None:
        post += planted(u - east, v - north)
        truth = _truth(planted, planted(u, v), pixel_size_m, crs_obj.is_geographic, rows, cols)
    pre += rng.normal(0.0, noise_m, size=pre.shape)
    post += rng.normal(0.0, noise_m, size=post.shape)
    return DsmPair(
        pre=pre.astype(np.float32),
        post=post.astype(np.float32),
        transform=transform,
        crs=crs_obj.to_string(),
        pixel_size_m=pixel_size_m,
        shift_m=(float(east), float(north), float(up)),
        tilt_m_per_km=(float(tilt_m_per_km[0]), float(tilt_m_per_km[1])),
        truth=truth,
    )


def _pixel_centres(transform: Affine, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    cc, rr = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    xs, ys = transform @ (cc, rr)
    return np.asarray(xs), np.asarray(ys)


def _truth(
    slide: _Slide,
    dz_on_grid: np.ndarray,
    pixel_size_m: float,
    geographic: bool,
    rows: int,
    cols: int,
) -> SlideTruth:
    mask = np.abs(dz_on_grid) > TRUTH_EPSILON_M
    if geographic:
        # Measure on a metric grid of the nominal pixel size centred like the raster.
        uu, vv = np.meshgrid(
            (np.arange(cols) + 0.5 - cols / 2) * pixel_size_m,
            (rows / 2 - np.arange(rows) - 0.5) * pixel_size_m,
        )
        dz_metric = slide(uu, vv)
    else:
        dz_metric = dz_on_grid
    pixel_area = pixel_size_m**2
    return SlideTruth(
        mask=mask,
        area_m2=float(np.count_nonzero(np.abs(dz_metric) > TRUTH_EPSILON_M) * pixel_area),
        volume_loss_m3=float(-dz_metric[dz_metric < 0].sum() * pixel_area),
        volume_gain_m3=float(dz_metric[dz_metric > 0].sum() * pixel_area),
    )


def write_dsm_pair(pair: DsmPair, out_dir: Path) -> DsmPairPaths:
    """Write `pre.tif` and `post.tif` (float32, nodata -9999, with CRS) into `out_dir`."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = DsmPairPaths(out_dir / "pre.tif", out_dir / "post.tif")
    for array, path in ((pair.pre, paths.pre), (pair.post, paths.post)):
        write_geotiff(path, array, pair.transform, rasterio.crs.CRS.from_user_input(pair.crs))
    return paths


__all__ = [
    "TRUTH_EPSILON_M",
    "DsmPair",
    "DsmPairPaths",
    "SlideSpec",
    "SlideTruth",
    "make_dsm_pair",
    "write_dsm_pair",
]
