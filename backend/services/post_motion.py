"""The post survey moved the way its comparison's co-registration moved it, for the map.

The co-registration (worker/pipeline/coregister.py) corrects the post DSM by a rotation
about the centre of the comparison's common grid and then a horizontal shift: a feature of
post at q, in the grid's CRS, lands at R(rotation) (q - centre) + centre + shift. The
comparison's summary keeps the shift and rotation (`shift_m`, `rotation_deg`), the centre
(`stages.coregister.tilt_pivot_east_m`/`_north_m`) and the grid's CRS (`stages.align.crs`).

An image drawn moved reads, for each pixel of the tile, the post raster where that motion
came from: the tile's positions go to the grid's CRS, back through the motion, then to the
raster's own CRS and pixels, and the raster is sampled there (bilinear).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from rasterio.crs import CRS
from rasterio.enums import ColorInterp, Resampling
from rasterio.io import DatasetReader
from rasterio.warp import transform as transform_points
from rasterio.windows import Window
from rio_tiler.models import ImageData
from scipy import ndimage

# The tile's positions are transformed exactly on a coarse grid of this many points a side
# and interpolated between (the map projections are smooth over a tile).
COARSE_POINTS = 17


@dataclass(frozen=True)
class PostMotion:
    """A co-registration's horizontal correction of the post survey (see the module doc)."""

    shift_east_m: float
    shift_north_m: float
    rotation_deg: float = 0.0
    centre_east_m: float = 0.0
    centre_north_m: float = 0.0
    crs: str | None = None  # the common grid's CRS; None: the raster's own

    @property
    def tag(self) -> str:
        """What tells tiles moved by different corrections apart (their cache key)."""
        return (
            f"{self.shift_east_m:.3f},{self.shift_north_m:.3f},{self.rotation_deg:.4f}"
            f"@{self.centre_east_m:.2f},{self.centre_north_m:.2f}"
        )

    def origin_of(self, east: np.ndarray, north: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where in post a point shown at (east, north) came from: the motion undone."""
        theta = math.radians(self.rotation_deg)
        u = east - self.shift_east_m - self.centre_east_m
        v = north - self.shift_north_m - self.centre_north_m
        cos, sin = math.cos(theta), math.sin(theta)
        return (
            self.centre_east_m + cos * u + sin * v,
            self.centre_north_m - sin * u + cos * v,
        )


def motion_from_summary(summary: Mapping[str, Any] | None) -> PostMotion | None:
    """The correction a comparison's summary states; None before its co-registration ran.
    A summary without the rotation's centre (made before rotations were estimated) has
    no rotation either: its shift alone."""
    summary = summary or {}
    shift = summary.get("shift_m")
    if not shift:
        return None
    stages = summary.get("stages") or {}
    coregister = stages.get("coregister") or {}
    centre = (coregister.get("tilt_pivot_east_m"), coregister.get("tilt_pivot_north_m"))
    rotation = float(summary.get("rotation_deg") or 0.0)
    if None in centre:
        rotation, centre = 0.0, (0.0, 0.0)
    return PostMotion(
        shift_east_m=float(shift.get("east", 0.0)),
        shift_north_m=float(shift.get("north", 0.0)),
        rotation_deg=rotation,
        centre_east_m=float(centre[0]),  # type: ignore[arg-type]
        centre_north_m=float(centre[1]),  # type: ignore[arg-type]
        crs=(stages.get("align") or {}).get("crs"),
    )


def _source_pixels(
    dataset: DatasetReader,
    bounds: tuple[float, float, float, float],
    bounds_crs: CRS,
    size: int,
    motion: PostMotion,
) -> tuple[np.ndarray, np.ndarray]:
    """Column and row (continuous, pixel edges at integers) of the raster that each of the
    size x size pixel centres of `bounds` shows once moved."""
    left, bottom, right, top = bounds
    steps = np.linspace(0.5, size - 0.5, COARSE_POINTS)
    cols, rows = np.meshgrid(steps, steps)
    x = left + cols * (right - left) / size
    y = top - rows * (top - bottom) / size
    grid_crs = CRS.from_user_input(motion.crs) if motion.crs else dataset.crs
    gx, gy = transform_points(bounds_crs, grid_crs, x.ravel(), y.ravel())
    ox, oy = motion.origin_of(np.asarray(gx), np.asarray(gy))
    sx, sy = transform_points(grid_crs, dataset.crs, ox, oy)
    col, row = ~dataset.transform * (np.asarray(sx), np.asarray(sy))
    # From the coarse grid to every pixel centre of the tile.
    at = np.arange(size) / (size - 1) * (COARSE_POINTS - 1)
    ii, jj = np.meshgrid(at, at, indexing="ij")
    coarse = (np.reshape(col, cols.shape), np.reshape(row, rows.shape))
    return tuple(ndimage.map_coordinates(c, [ii, jj], order=1, mode="nearest") for c in coarse)  # type: ignore[return-value]


def _alpha_index(dataset: DatasetReader) -> int | None:
    for index, interp in enumerate(dataset.colorinterp, start=1):
        if interp == ColorInterp.alpha:
            return index
    return None


def moved_image(
    dataset: DatasetReader,
    bounds: tuple[float, float, float, float],
    bounds_crs: CRS,
    size: int,
    motion: PostMotion,
) -> ImageData:
    """The colour raster's pixels over `bounds` (size x size), moved by `motion`; masked
    where the raster has no data (its alpha band, else its mask) or none reaches."""
    col, row = _source_pixels(dataset, bounds, bounds_crs, size, motion)
    colour = [i for i in range(1, dataset.count + 1) if i != _alpha_index(dataset)][:3]
    empty = np.ma.MaskedArray(
        np.zeros((len(colour), size, size), dtype=np.uint8), mask=np.ones((len(colour), size, size))
    )
    # The window of the raster the tile needs, read at about the tile's resolution (GDAL
    # takes an overview when there is one).
    col_off = max(0, math.floor(col.min()) - 2)
    row_off = max(0, math.floor(row.min()) - 2)
    col_end = min(dataset.width, math.ceil(col.max()) + 2)
    row_end = min(dataset.height, math.ceil(row.max()) + 2)
    if col_end <= col_off or row_end <= row_off:
        return ImageData(empty, bounds=bounds, crs=bounds_crs)
    width, height = col_end - col_off, row_end - row_off
    factor = max(1, math.floor(max(np.ptp(col), np.ptp(row)) / size))
    shape = (max(1, math.ceil(height / factor)), max(1, math.ceil(width / factor)))
    window = Window(col_off, row_off, width, height)
    read = dataset.read(colour, window=window, out_shape=(len(colour), *shape),
                        resampling=Resampling.bilinear)  # fmt: skip
    alpha = _alpha_index(dataset)
    if alpha is not None:
        valid = dataset.read(alpha, window=window, out_shape=shape, resampling=Resampling.nearest)
    else:
        valid = dataset.read_masks(1, window=window, out_shape=shape)
    # Continuous raster pixels to indices of the (decimated) window's pixel centres.
    ci = (col - col_off) * shape[1] / width - 0.5
    ri = (row - row_off) * shape[0] / height - 0.5
    bands = np.stack(
        [
            ndimage.map_coordinates(band.astype(np.float32), [ri, ci], order=1, cval=0.0)
            for band in read
        ]
    )
    reached = ndimage.map_coordinates(
        (valid > 0).astype(np.float32), [ri, ci], order=1, mode="constant", cval=0.0
    )
    mask = np.broadcast_to(reached < 0.5, bands.shape)
    pixels = np.clip(np.rint(bands), 0, 255).astype(np.uint8)
    return ImageData(np.ma.MaskedArray(pixels, mask=mask), bounds=bounds, crs=bounds_crs)
