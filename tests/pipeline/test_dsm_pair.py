"""The synthetic DSM pair: deterministic, exact shift, realistic slopes, conserved volume."""

import numpy as np
import rasterio

from worker.simulator.dsm_pair import SlideSpec, make_dsm_pair, write_dsm_pair


def test_same_seed_gives_identical_pairs_and_other_seeds_differ():
    a = make_dsm_pair((120, 100), seed=5)
    b = make_dsm_pair((120, 100), seed=5)
    c = make_dsm_pair((120, 100), seed=6)
    assert np.array_equal(a.pre, b.pre) and np.array_equal(a.post, b.post)
    assert not np.array_equal(a.pre, c.pre)


def test_post_is_the_terrain_evaluated_at_shifted_coordinates():
    pair = make_dsm_pair((200, 200), 1.0, shift_m=(3.0, -2.0, 0.25), slide=False, noise_m=0.0)
    # A shift of (+3 px east, -2 px north) moves every value 3 columns right, 2 rows down.
    np.testing.assert_allclose(pair.post[2:, 3:], pair.pre[:-2, :-3] + 0.25, atol=1e-4)


def test_terrain_has_real_slopes_and_every_aspect():
    pair = make_dsm_pair((400, 400), 1.0, slide=False, noise_m=0.0, seed=3)
    grad_y, grad_x = np.gradient(pair.pre.astype(np.float64))
    slope = np.degrees(np.arctan(np.hypot(grad_x, grad_y)))
    p10, median, p90 = np.percentile(slope, [10, 50, 90])
    assert 3 < p10 < 12 and 10 < median < 30 and 25 < p90 < 45
    aspect = np.degrees(np.arctan2(-grad_x, grad_y)) % 360
    counts, _ = np.histogram(aspect, bins=8, range=(0, 360))
    assert counts.min() > 0.01 * aspect.size


def test_slide_conserves_volume_and_truth_matches_mask():
    pair = make_dsm_pair((400, 400), 1.0, slide=True, noise_m=0.0, seed=4)
    truth = pair.truth
    assert truth is not None
    assert truth.area_m2 == np.count_nonzero(truth.mask) * 1.0
    assert truth.volume_loss_m3 > 1000
    assert abs(truth.volume_loss_m3 - truth.volume_gain_m3) / truth.volume_loss_m3 < 0.005
    change = pair.post - pair.pre
    assert change[truth.mask].min() < -2.0 and change[truth.mask].max() > 1.0
    np.testing.assert_allclose(change[~truth.mask], 0.0, atol=1e-3)


def test_slide_spec_scales_the_slide():
    small = make_dsm_pair((300, 300), slide=SlideSpec(depth_m=1.0), noise_m=0.0, seed=1)
    big = make_dsm_pair((300, 300), slide=SlideSpec(depth_m=3.0), noise_m=0.0, seed=1)
    assert small.truth is not None and big.truth is not None
    ratio = big.truth.volume_loss_m3 / small.truth.volume_loss_m3
    assert abs(ratio - 3.0) < 0.01


def test_geographic_variant_and_written_files(tmp_path):
    pair = make_dsm_pair((150, 120), 0.5, crs="EPSG:4326", origin=(9.5, 46.2), seed=2)
    assert pair.crs == "EPSG:4326"
    assert abs(pair.transform.c - 9.5) < 1e-12 and abs(pair.transform.f - 46.2) < 1e-12
    assert pair.truth is not None and pair.truth.area_m2 > 0
    pair.pre[0, 0] = np.nan
    paths = write_dsm_pair(pair, tmp_path)
    with rasterio.open(paths.pre) as src:
        assert src.crs.to_epsg() == 4326
        assert src.nodata == -9999
        data = src.read(1, masked=True)
        assert data.mask[0, 0] and not data.mask[0, 1]
        assert (src.height, src.width) == (150, 120)
