"""Two surveys metres apart (stand-alone GNSS) over small features: phase correlation finds
the shift that Nuth & Kääb alone cannot reach, and Nuth & Kääb refines it."""

import cv2
import numpy as np
import pytest
from rasterio.transform import Affine

from worker.pipeline.coarse_shift import coarse_shift
from worker.pipeline.coregister import CoregisterOptions, coregister
from worker.pipeline.raster_io import write_geotiff

PIXEL_M = 0.5
SIZE, PAD = 360, 40


def mound_field(seed: int) -> np.ndarray:
    """Flat ground with 300 mounds 1-2 m high and a few pixels wide (larger than the DSM
    by PAD on each side, so that shifted crops stay inside it)."""
    rng = np.random.default_rng(seed)
    field = np.zeros((SIZE + 2 * PAD, SIZE + 2 * PAD), np.float32)
    rows, cols = rng.integers(0, field.shape[0], (2, 300))
    np.add.at(field, (rows, cols), rng.uniform(1, 2, 300).astype(np.float32))
    return cv2.GaussianBlur(field, (0, 0), 2.5) * 40 + 100


def surveys(shift_px: tuple[int, int], seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """pre, and post whose ground appears `shift_px` (columns east, rows south) away,
    0.4 m higher, both with 2 cm of noise."""
    field = mound_field(seed)
    rng = np.random.default_rng(seed + 1)
    sx, sy = shift_px
    pre = field[PAD : PAD + SIZE, PAD : PAD + SIZE]
    post = field[PAD - sy : PAD - sy + SIZE, PAD - sx : PAD - sx + SIZE] + 0.4
    noise = rng.normal(0, 0.02, (2, SIZE, SIZE)).astype(np.float32)
    return pre + noise[0], post + noise[1]


@pytest.mark.parametrize("shift_px", [(-25, 18), (30, 4), (12, -22)])
def test_phase_correlation_finds_a_shift_larger_than_the_features(shift_px):
    pre, post = surveys(shift_px)
    found = coarse_shift(pre, post, PIXEL_M, PIXEL_M)
    assert found.used and found.response > 0.2
    # The correction is the opposite of the displacement (rows run south).
    assert found.east_m / PIXEL_M == pytest.approx(-shift_px[0], abs=1.0)
    assert found.north_m / PIXEL_M == pytest.approx(shift_px[1], abs=1.0)


def test_coregistration_recovers_a_25_pixel_shift_within_a_tenth_of_a_pixel(tmp_path):
    pre, post = surveys((-25, 18))
    transform = Affine(PIXEL_M, 0, 500_000, 0, -PIXEL_M, 5_100_000)
    write_geotiff(tmp_path / "pre.tif", pre, transform, "EPSG:32632")
    write_geotiff(tmp_path / "post.tif", post, transform, "EPSG:32632")
    result = coregister(tmp_path / "pre.tif", tmp_path / "post.tif", tmp_path / "out.tif")
    assert result.shift_east_px == pytest.approx(25, abs=0.1)
    assert result.shift_north_px == pytest.approx(18, abs=0.1)
    assert result.shift_up_m == pytest.approx(-0.4, abs=0.01)
    assert abs(result.initial_shift_east_m / PIXEL_M - 25) <= 1
    # Nuth & Kääb alone settles far from it: the mounds are smaller than the shift.
    alone = coregister(
        tmp_path / "pre.tif",
        tmp_path / "post.tif",
        tmp_path / "alone.tif",
        CoregisterOptions(coarse_shift=False),
    )
    assert abs(alone.shift_east_px - 25) > 5 and alone.initial_shift_east_m == 0.0


def test_no_shift_is_taken_from_noise():
    rng = np.random.default_rng(3)
    pre = rng.normal(100, 0.05, (300, 300)).astype(np.float32)
    post = rng.normal(100, 0.05, (300, 300)).astype(np.float32)
    found = coarse_shift(pre, post, 1.0, 1.0)
    assert not found.used or abs(found.east_m) + abs(found.north_m) < 2.0
    empty = np.full((300, 300), np.nan, np.float32)
    assert coarse_shift(pre, empty, 1.0, 1.0).used is False
