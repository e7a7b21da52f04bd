"""coregister: sub-pixel shift recovery with and without a landslide, tilt, flat terrain."""

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from worker.pipeline.coregister import CoregisterOptions, coregister
from worker.pipeline.errors import InputError
from worker.pipeline.raster_io import read_elevation, warp_elevation, write_geotiff
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair

PIXEL_M = 1.0


def _coregister(tmp_path, pair, options=None):
    paths = write_dsm_pair(pair, tmp_path / "in")
    result = coregister(
        paths.pre,
        paths.post,
        tmp_path / "post_c.tif",
        options,
        stable_mask_out=tmp_path / "stable.tif",
    )
    return paths, result


@pytest.mark.parametrize(
    ("shift", "slide", "seed"),
    [
        ((0.3, -0.2, 0.5), False, 1),  # sub-pixel
        ((0.5, 0.5, 0.0), True, 2),  # half a pixel, the worst case for interpolation
        ((2.7, -1.6, 0.4), True, 3),  # multi-pixel
        ((-4.2, 3.3, -1.0), True, 4),  # multi-pixel, other quadrant
    ],
)
def test_shift_recovered_within_a_tenth_of_a_pixel(tmp_path, shift, slide, seed):
    pair = make_dsm_pair((300, 300), PIXEL_M, shift, slide=slide, noise_m=0.05, seed=seed)
    _, result = _coregister(tmp_path, pair)
    # The result is the correction applied to post: the opposite of the simulated shift.
    assert abs(result.shift_east_m + shift[0]) / PIXEL_M < 0.1
    assert abs(result.shift_north_m + shift[1]) / PIXEL_M < 0.1
    assert abs(result.shift_up_m + shift[2]) < 0.02
    assert result.shift_east_px == pytest.approx(result.shift_east_m / PIXEL_M)
    assert result.horizontal_estimated and result.notes == []
    assert result.nmad_after_m < 0.1 <= result.nmad_before_m or shift[:2] == (0.3, -0.2)
    assert result.nmad_after_m < result.nmad_before_m
    assert abs(result.median_after_m) < 0.01


def test_corrected_post_matches_pre_off_the_slide(tmp_path):
    pair = make_dsm_pair((300, 300), PIXEL_M, (1.6, -0.7, 0.3), slide=True, noise_m=0.0, seed=5)
    _coregister(tmp_path, pair)
    corrected, _ = read_elevation(tmp_path / "post_c.tif")
    dh = corrected - pair.pre
    assert pair.truth is not None
    stable = ~pair.truth.mask & np.isfinite(dh)
    assert np.abs(np.median(dh[stable])) < 0.005
    assert np.percentile(np.abs(dh[stable]), 95) < 0.05


def test_stable_mask_excludes_the_landslide(tmp_path):
    pair = make_dsm_pair((300, 300), PIXEL_M, (1.1, 0.4, 0.0), slide=True, seed=6)
    _, result = _coregister(tmp_path, pair)
    with rasterio.open(tmp_path / "stable.tif") as src:
        mask = src.read(1)
        assert src.nodata == 255 and src.dtypes[0] == "uint8"
    assert pair.truth is not None
    deep = pair.truth.mask & (np.abs(pair.post - pair.pre) > 0.5)
    assert np.all(mask[deep] == 0)
    assert 0.85 < result.stable_fraction < 0.99
    assert result.iterations >= 2


def test_tilt_is_estimated_and_removed(tmp_path):
    pair = make_dsm_pair(
        (300, 300), PIXEL_M, (2.2, 1.3, 0.2), slide=True, seed=7, tilt_m_per_km=(2.0, -1.5)
    )
    _, result = _coregister(tmp_path, pair)
    assert result.tilt_east_m_per_km == pytest.approx(-2.0, abs=0.05)
    assert result.tilt_north_m_per_km == pytest.approx(1.5, abs=0.05)
    assert abs(result.shift_east_m + 2.2) < 0.1 and abs(result.shift_north_m + 1.3) < 0.1
    assert abs(result.shift_up_m + 0.2) < 0.02
    no_tilt = CoregisterOptions(tilt=False)
    _, untilted = _coregister(tmp_path / "plain", pair, no_tilt)
    assert untilted.tilt_east_m_per_km is None
    assert untilted.nmad_after_m > result.nmad_after_m


def test_flat_terrain_gets_only_a_vertical_shift(tmp_path):
    pair = make_dsm_pair((300, 300), PIXEL_M, (0.8, 0.5, 0.35), slide=False, seed=8, terrain="flat")
    _, result = _coregister(tmp_path, pair)
    assert not result.horizontal_estimated
    assert result.shift_east_m == 0.0 and result.shift_north_m == 0.0
    assert result.shift_up_m == pytest.approx(-0.35, abs=0.01)
    assert "flat terrain" in result.notes[0]


def test_grids_must_match(tmp_path):
    pair = make_dsm_pair((100, 100), slide=False)
    write_geotiff(tmp_path / "pre.tif", pair.pre, pair.transform, "EPSG:32632")
    write_geotiff(tmp_path / "post.tif", pair.post[:90], pair.transform, "EPSG:32632")
    with pytest.raises(InputError, match="same grid"):
        coregister(tmp_path / "pre.tif", tmp_path / "post.tif", tmp_path / "out.tif")
    assert not (tmp_path / "out.tif").exists()


def test_correct_points_moves_post_features_onto_pre(tmp_path):
    # Checkpoints as the post survey placed them (shifted, raised and tilted) must land
    # where pre has them once the estimated correction is applied.
    shift, tilt = (2.4, -1.7, 0.6), (1.5, -2.5)
    pair = make_dsm_pair((300, 300), PIXEL_M, shift, slide=False, seed=9, tilt_m_per_km=tilt)
    _, result = _coregister(tmp_path, pair)
    assert result.tilt_pivot_east_m == pytest.approx(500_150.0)
    assert result.tilt_pivot_north_m == pytest.approx(5_099_850.0)
    rows, cols = np.array([30, 150, 260]), np.array([40, 150, 270])
    x, y = pair.transform * (cols + 0.5, rows + 0.5)
    on_pre = np.column_stack([x, y, pair.pre[rows, cols]])
    moved_x, moved_y = x + shift[0], y + shift[1]
    u, v = moved_x - result.tilt_pivot_east_m, moved_y - result.tilt_pivot_north_m
    on_post = np.column_stack(
        [moved_x, moved_y, on_pre[:, 2] + shift[2] + (tilt[0] * u + tilt[1] * v) / 1000.0]
    )
    corrected = result.correct_points(on_post)
    assert np.abs(corrected[:, :2] - on_pre[:, :2]).max() < 0.1 * PIXEL_M
    assert np.abs(corrected[:, 2] - on_pre[:, 2]).max() < 0.02
    raw_error = np.abs(on_post - on_pre).max(axis=0)
    assert raw_error[0] > 2.0 and raw_error[2] > 0.5


def test_rotation_is_estimated_and_the_points_follow_it(tmp_path):
    # Post turned 0.2° about the grid centre and shifted: its corners are 0.7 m off, and
    # a shift alone leaves dh of decimetres on the slopes.
    pair = make_dsm_pair((300, 300), PIXEL_M, (1.3, -0.8, 0.2), slide=True, noise_m=0.03, seed=11)
    paths = write_dsm_pair(pair, tmp_path / "in")
    with rasterio.open(paths.post) as src:
        profile, post = src.profile, src.read(1)
    rows, cols = post.shape
    cx, cy = pair.transform * (cols / 2, rows / 2)
    turned = Affine.rotation(0.2, pivot=(cx, cy)) @ pair.transform
    rotated = warp_elevation(
        post, turned, profile["crs"], pair.transform, profile["crs"], post.shape
    )
    write_geotiff(paths.post, rotated, pair.transform, profile["crs"])

    result = coregister(paths.pre, paths.post, tmp_path / "post_c.tif")
    plain = coregister(
        paths.pre, paths.post, tmp_path / "plain.tif", CoregisterOptions(rotation=False)
    )
    assert result.rotation_deg == pytest.approx(-0.2, abs=0.01)
    assert plain.rotation_deg == 0.0
    assert result.nmad_after_m < 0.6 * plain.nmad_after_m
    corrected, _ = read_elevation(tmp_path / "post_c.tif")
    stable = ~pair.truth.mask & np.isfinite(corrected)
    assert np.percentile(np.abs(corrected - pair.pre)[stable], 95) < 0.1

    # A feature of post lands where pre has it.
    r, c = np.array([20, 150, 280]), np.array([25, 150, 270])
    x, y = pair.transform * (c + 0.5, r + 0.5)
    centre = np.array([cx, cy])
    turn = np.radians(0.2)
    rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    moved = (np.column_stack([x, y]) - centre) @ rot.T + centre + np.array([1.3, -0.8])
    on_post = np.column_stack([moved, pair.pre[r, c] + 0.2])
    back = result.correct_points(on_post)
    assert np.abs(back[:, 0] - x).max() < 0.1 and np.abs(back[:, 1] - y).max() < 0.1
