"""Fixed and loose crops, flips, registration jitter and the scale-free normalisation."""

import numpy as np
import pytest

from worker.pipeline.cnn.normalize import dense_inputs, relative_patch_pair, vertical_level_m
from worker.pipeline.cnn.patches import centre_crop
from worker.training.augment import (
    fixed_crop,
    loose_crop,
    random_flips,
    registration_jitter,
)


def _patches(n=400, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(0, 1, (n, 42, 42)), rng.normal(0, 1, (n, 42, 42))


def test_fixed_crop_is_the_centre():
    pre, post = _patches(3)
    a, b = fixed_crop(pre, post)
    np.testing.assert_array_equal(a, pre[:, 5:37, 5:37])
    np.testing.assert_array_equal(b, post[:, 5:37, 5:37])


@pytest.mark.parametrize("pixel_size", [0.02, 0.2])
def test_loose_crop_stays_in_the_margin_and_offsets_are_bounded(pixel_size):
    pre, post = _patches()
    rng = np.random.default_rng(1)
    a, b, shifts, offsets = loose_crop(pre, post, pixel_size, rng)
    assert shifts.min() == -5 and shifts.max() == 5  # every shift is drawn over 400 samples
    level = 0.6 * pixel_size
    assert vertical_level_m(pixel_size) == pytest.approx(level)
    assert np.abs(offsets).max() == pytest.approx(10 * level)  # 0.12 m at 2 cm
    np.testing.assert_allclose(offsets / level, np.round(offsets / level), atol=1e-9)
    np.testing.assert_allclose(b, centre_crop(post), rtol=1e-6, atol=1e-6)
    for k in range(len(pre)):
        r, c = 5 + shifts[k, 0], 5 + shifts[k, 1]
        np.testing.assert_allclose(a[k], pre[k, r : r + 32, c : c + 32] + offsets[k], atol=1e-5)


def test_flips_move_both_channels_alike():
    a, b = _patches(50)
    (fa, fb), flags = random_flips(np.random.default_rng(2), a, b)
    for k in range(50):
        expect = a[k]
        if flags[k, 0]:
            expect = expect[::-1, :]
        if flags[k, 1]:
            expect = expect[:, ::-1]
        np.testing.assert_array_equal(fa[k], expect)
        np.testing.assert_array_equal(
            fb[k] - fa[k],
            (b[k] - a[k])[tuple(slice(None, None, -1) if f else slice(None) for f in flags[k])],
        )


def test_registration_jitter_moves_the_post_tile():
    window = np.arange(20 * 20, dtype=np.float64).reshape(20, 20)
    out = registration_jitter(window, (10, 10), 5, (2.0, -3.0), 0.5)
    np.testing.assert_allclose(out, window[7:17, 2:12] + 0.5)
    half = registration_jitter(window, (10, 10), 5, (0.5, 0.0), 0.0)
    np.testing.assert_allclose(half, (window[5:15, 5:15] + window[6:16, 5:15]) / 2, atol=1e-4)


def test_normalisation_serves_2cm_and_20cm_alike():
    rng = np.random.default_rng(4)
    pre = rng.normal(0, 0.05, (3, 32, 32)) + 25.0
    post = pre + rng.normal(0, 0.02, (3, 32, 32))
    a2, b2 = relative_patch_pair(pre, post, 0.02)
    a20, b20 = relative_patch_pair(pre * 10 + 400, post * 10 + 400, 0.2)
    np.testing.assert_allclose(a2, a20, atol=1e-3)
    np.testing.assert_allclose(b2 - a2, b20 - a20, atol=1e-3)
    assert np.abs(a2.mean(axis=(1, 2))).max() < 1e-4  # relative to the pre patch's mean
    dense2 = dense_inputs(pre[0], post[0], 0.02)
    dense20 = dense_inputs(pre[0] * 10 + 400, post[0] * 10 + 400, 0.2)
    np.testing.assert_allclose(dense2, dense20, atol=1e-3)


def test_nodata_is_flat_and_invalid():
    pre = np.full((16, 16), 3.0)
    post = pre.copy()
    post[4, 4] = np.nan
    x = dense_inputs(pre, post, 0.1)
    assert x[3, 4, 4] == 0 and x[3].sum() == 255
    assert np.all(x[:3, 4, 4] == 0)
