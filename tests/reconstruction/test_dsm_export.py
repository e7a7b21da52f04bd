"""DSM gridding, Fast Marching inpainting, COG and grey-scale PNG on hand-made points."""

import cv2
import numpy as np
import pytest
import rasterio
from rio_cogeo.cogeo import cog_validate

from worker.pipeline.dsm_export import (
    FILLED_INPAINTED,
    FILLED_MEASURED,
    FILLED_OUTSIDE,
    DsmOptions,
    auto_resolution,
    export_dsm,
    footprint,
    grey_png,
    grid_points,
    inpaint,
)
from worker.pipeline.errors import InputError

E0, N0 = 500_000.0, 4_000_000.0


def test_mean_and_median_per_cell_on_a_snapped_grid():
    pts = np.array(
        [
            [E0 + 0.2, N0 + 0.7, 1.0],
            [E0 + 0.4, N0 + 0.6, 2.0],
            [E0 + 0.9, N0 + 0.1, 3.0],  # cell (row 0, col 0) of a 1 m grid: 1, 2, 3
            [E0 + 1.5, N0 + 0.5, 10.0],
            [E0 + 1.6, N0 + 0.5, 11.0],
            [E0 + 1.7, N0 + 0.5, 100.0],  # cell (0, 1): an outlier among 10, 11
        ]
    )
    mean = grid_points(pts, 1.0, statistic="mean")
    assert mean.values.shape == (1, 2)
    assert (mean.transform.c, mean.transform.f) == (E0, N0 + 1.0)
    np.testing.assert_allclose(mean.values[0], [2.0, 121.0 / 3], rtol=1e-6)
    np.testing.assert_array_equal(mean.counts[0], [3, 3])
    median = grid_points(pts, 1.0, statistic="median")
    np.testing.assert_allclose(median.values[0], [2.0, 11.0])
    even = grid_points(pts[:2], 1.0, statistic="median")
    assert even.values[0, 0] == pytest.approx(1.5)


def test_explicit_bounds_and_empty_cells_are_nan():
    pts = np.array([[E0 + 0.5, N0 + 0.5, 5.0], [E0 + 2.5, N0 + 0.5, 7.0]])
    grid = grid_points(pts, 1.0, bounds=(E0, N0, E0 + 4, N0 + 2))
    assert grid.values.shape == (2, 4)
    assert grid.values[1, 0] == 5.0 and grid.values[1, 2] == 7.0
    assert np.isnan(grid.values[0]).all() and np.isnan(grid.values[1, [1, 3]]).all()


def _plane(res: float = 0.1, size: int = 60, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, size * res, (size * size * 6, 2))
    z = 100.0 + 0.3 * xy[:, 0] - 0.2 * xy[:, 1]
    return np.column_stack([xy[:, 0] + E0, xy[:, 1] + N0, z])


def test_telea_inpainting_fills_a_hole_and_keeps_a_mask():
    pts = _plane()
    x, y = pts[:, 0] - E0, pts[:, 1] - N0
    hole = (np.abs(x - 3.0) < 0.6) & (np.abs(y - 3.0) < 0.6)
    grid = grid_points(pts[~hole], 0.1, bounds=(E0, N0, E0 + 6, N0 + 6))
    assert np.isnan(grid.values).sum() >= 100
    filled = inpaint(grid, radius_px=3, max_gap_px=20)
    assert np.isfinite(filled.values).all()
    cx, cy = np.meshgrid(np.arange(60) * 0.1 + 0.05, 6 - (np.arange(60) * 0.1 + 0.05))
    truth = 100.0 + 0.3 * cx - 0.2 * cy
    was_hole = filled.filled == FILLED_INPAINTED
    assert was_hole.sum() == np.isnan(grid.values).sum()
    # Telea's Fast Marching is a first-order extrapolation from the hole's rim: on a
    # 0.36 m/m plane across a 1.2 m hole it stays within a few decimetres.
    error = np.abs(filled.values[was_hole] - truth[was_hole])
    assert error.max() < 0.2 and error.mean() < 0.06
    assert (filled.filled[~was_hole] == FILLED_MEASURED).all()


def test_no_extrapolation_outside_the_footprint():
    pts = _plane()
    keep = (pts[:, 0] - E0) < 3.0  # data only in the western half
    grid = grid_points(pts[keep], 0.1, bounds=(E0, N0, E0 + 6, N0 + 6))
    filled = inpaint(grid, max_gap_px=5)
    assert np.isnan(filled.values[:, 40:]).all()
    assert (filled.filled[:, 40:] == FILLED_OUTSIDE).all()


def test_footprint_closes_narrow_gaps_fills_holes_and_keeps_wide_openings():
    ring = np.zeros((40, 40), bool)
    ring[5:35, 5:35] = True
    ring[8:32, 8:32] = False  # a 24-cell hole inside a 3-cell wall
    ring[5:8, 18:22] = False  # a 4-cell gap through the wall
    closed = footprint(ring, max_gap_px=6)
    assert closed[5:35, 5:35].all()  # gap closed, hole filled
    assert not closed[:5].any() and not closed[35:].any() and not closed[:, :5].any()
    assert closed.sum() == 30 * 30

    opened = ring.copy()
    opened[5:8, 10:30] = False  # a 20-cell opening: wider than any gap to close
    wide = footprint(opened, max_gap_px=6)
    assert not wide[20, 20] and wide[6, 6] and not wide[6, 20]
    assert (footprint(ring, max_gap_px=0) == ring).all()  # nothing closed, hole open


def test_grey_png_scaling_like_the_paper():
    values = np.array([[100.0, 100.012, 100.6], [np.nan, 104.0, 99.0]])
    image, base = grey_png(values, 0.012, base_m=100.0)
    assert base == 100.0
    assert image.tolist() == [[1, 2, 51], [0, 255, 1]]


def test_export_writes_a_valid_cog_mask_and_png(tmp_path):
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 60.0, (400_000, 2))
    z = 250.0 + np.sin(xy[:, 0] / 5.0) + 0.05 * xy[:, 1]
    gap = np.hypot(xy[:, 0] - 30, xy[:, 1] - 30) < 2.0
    pts = np.column_stack([xy[:, 0] + E0, xy[:, 1] + N0, z])[~gap]
    options = DsmOptions(resolution_m=0.1, png=True, max_gap_m=1.0)
    result = export_dsm(pts, "EPSG:32633", tmp_path, options)
    assert result.crs == "EPSG:32633" and (result.width, result.height) == (600, 600)
    # ~1.1 points per 10 cm cell: a third of the cells are empty before filling.
    assert 0.6 < result.completeness < 0.7 and result.filled_cells > 100_000
    valid, errors, _ = cog_validate(result.dsm_path, quiet=True)
    assert valid, errors
    with rasterio.open(result.dsm_path) as src:
        assert src.crs.to_epsg() == 32633 and src.nodata == -9999
        assert src.overviews(1)
        dsm = src.read(1)
        assert src.profile["compress"].lower() == "deflate"
    assert (dsm != -9999).all()
    assert abs(dsm[300, 300] - (250.0 + np.sin(30.05 / 5.0) + 0.05 * 29.95)) < 0.15
    with rasterio.open(result.filled_mask_path) as src:
        mask = src.read(1)
    assert mask[300, 300] == FILLED_INPAINTED and mask[10, 10] == FILLED_MEASURED
    png = cv2.imread(result.png_path, cv2.IMREAD_UNCHANGED)
    assert png.shape == (600, 600) and png.dtype == np.uint8 and png.min() >= 1
    assert not list(tmp_path.glob(".*"))  # no temporary files left


def test_auto_resolution_from_point_spacing():
    g = np.mgrid[0:100, 0:100].reshape(2, -1).T * 0.05
    pts = np.column_stack([g + np.array([E0, N0]), np.zeros(len(g))])
    assert auto_resolution(pts) == pytest.approx(0.1)


def test_bad_inputs():
    pts = _plane()
    with pytest.raises(InputError, match="metric projected CRS"):
        export_dsm(pts, "EPSG:4326", ".")
    with pytest.raises(InputError, match="empty"):
        grid_points(np.empty((0, 3)), 1.0)
    with pytest.raises(InputError, match="statistic"):
        grid_points(pts, 1.0, statistic="mode")
