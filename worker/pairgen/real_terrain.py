"""Real relief: windows of a real DEM, scaled down with their slopes kept.

The one elevation model that ships in an installed package is matplotlib's sample DEM
of the Jacksboro fault (Cumberland Mountains, Tennessee; USGS 3 arc-second, about
74 m x 93 m per cell, 236-1076 m). Its ridges, hollows, spurs and valley floors were
made by erosion, not by a noise model, so a detector tuned on synthetic landforms meets
land shapes it has not seen.

A window of the DEM is taken at a random place, turned by a multiple of 90° and maybe
mirrored, and scaled by `scale` (pair metres per real metre) in all three axes: a pair
of 500 one-metre pixels covers 500 / scale real metres, and every slope keeps its real
angle. Below the DEM's own cell the relief is smooth, so it gets the roughness a finer
survey would see: power-law relief up to the scaled cell size and decimetre texture.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy import ndimage

from worker.pairgen.fields import power_law_field, rms_gradient

SAMPLE = "jacksboro_fault_dem.npz"
METRES_PER_DEGREE = 111_320.0


@functools.lru_cache(maxsize=1)
def sample_dem() -> tuple[np.ndarray, float, float]:
    """(heights in metres, row spacing m, column spacing m) of the shipped sample DEM."""
    from matplotlib import cbook

    with cbook.get_sample_data(SAMPLE) as data:
        heights = np.asarray(data["elevation"], dtype=np.float64)
        latitude = 0.5 * (float(data["ymin"]) + float(data["ymax"]))
        row_m = float(data["dy"]) * METRES_PER_DEGREE
        col_m = float(data["dx"]) * METRES_PER_DEGREE * np.cos(np.radians(latitude))
    return heights, row_m, col_m


def real_relief(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    cell_px: tuple[float, float] = (4.0, 8.0),
    roughness_m: tuple[float, float] = (0.02, 0.06),
) -> np.ndarray:
    """A window of the sample DEM on `shape`, one DEM cell spanning `cell_px` pixels."""
    dem, row_m, col_m = sample_dem()
    turns = int(rng.integers(4))
    dem = np.rot90(dem, turns)
    if turns % 2:
        row_m, col_m = col_m, row_m
    if rng.uniform() < 0.5:
        dem = dem[:, ::-1]
    cell = rng.uniform(*cell_px) * pixel_size  # pair metres per DEM row
    scale = cell / row_m  # pair metres per real metre
    rows_needed = shape[0] * pixel_size / scale / row_m
    cols_needed = shape[1] * pixel_size / scale / col_m
    if rows_needed > dem.shape[0] - 2 or cols_needed > dem.shape[1] - 2:
        raise ValueError("the pair is larger than the sample DEM at this scale")
    r0 = rng.uniform(0, dem.shape[0] - 1 - rows_needed)
    c0 = rng.uniform(0, dem.shape[1] - 1 - cols_needed)
    rr = r0 + (np.arange(shape[0]) + 0.5) * rows_needed / shape[0]
    cc = c0 + (np.arange(shape[1]) + 0.5) * cols_needed / shape[1]
    grid = np.meshgrid(rr, cc, indexing="ij")
    z = ndimage.map_coordinates(dem, grid, order=3, mode="nearest") * scale
    # What the DEM cannot show: relief finer than its cell, and surface texture.
    fine = power_law_field(shape, pixel_size, rng, beta=3.2, outer_m=cell, inner_m=2 * pixel_size)
    g = rms_gradient(fine, pixel_size)
    if g > 0:
        z += fine * (0.1 / g)
    texture = power_law_field(shape, pixel_size, rng, beta=3.0, outer_m=2.0)
    return z + rng.uniform(*roughness_m) * texture
