"""Patch extraction and labelling rules, cell by cell: margin, stride, the 10 % rule."""

import numpy as np
import pytest

from worker.pipeline.cnn.patches import (
    CORE_PX,
    MARGIN_PX,
    PATCH_PX,
    STRIDE_PX,
    balance_classes,
    centre_fractions,
    centres_inside,
    extract_patches,
    label_from_fraction,
    patch_origins,
)


def test_layout_constants():
    assert (PATCH_PX, CORE_PX, MARGIN_PX, STRIDE_PX) == (42, 32, 5, 10)


def test_grid_origins_keep_every_window_inside():
    rows, cols = patch_origins((100, 80))
    assert rows.tolist() == [0, 10, 20, 30, 40, 50]  # 50 + 42 <= 100 < 60 + 42
    assert cols.tolist() == [0, 10, 20, 30]  # 30 + 42 <= 80 < 40 + 42
    rows, cols = patch_origins((41, 500))
    assert rows.size == 0


def test_windows_and_centres_are_where_the_layout_says():
    shape = (90, 73)
    index = np.arange(shape[0] * shape[1], dtype=np.float64).reshape(shape)
    mask = np.zeros(shape, np.uint8)
    patches = extract_patches(index, index + 0.5, mask, 0.02)
    rows, cols = patch_origins(shape)
    assert len(patches) == rows.size * cols.size
    for k in range(len(patches)):
        r, c = patches.rows[k], patches.cols[k]
        np.testing.assert_array_equal(patches.pre[k], index[r : r + 42, c : c + 42])
        np.testing.assert_array_equal(patches.post[k], index[r : r + 42, c : c + 42] + 0.5)
        centre = patches.pre[k][5:37, 5:37]
        np.testing.assert_array_equal(centre, index[r + 5 : r + 37, c + 5 : c + 37])


def test_ten_percent_rule_counts_only_the_centre():
    mask = np.zeros((42, 42), np.uint8)
    ys, xs = np.divmod(np.arange(102), 32)
    mask[5 + ys, 5 + xs] = 1  # 102 of 1024 centre pixels: 9.96 %
    mask[:5, :] = 1  # the margin does not count
    mask[:, 37:] = 1
    z = np.zeros((42, 42))
    assert extract_patches(z, z, mask, 0.02).labels.tolist() == [0]
    mask[5 + 3, 5 + 6] = 1  # 103 pixels: 10.06 %
    patches = extract_patches(z, z, mask, 0.02)
    assert patches.labels.tolist() == [1]
    assert patches.fraction[0] == pytest.approx(103 / 1024)


def test_labels_cell_by_cell_match_brute_force():
    rng = np.random.default_rng(3)
    mask = (rng.random((123, 141)) < 0.1).astype(np.uint8)
    mask[30:80, 40:100] = 1
    rows, cols = patch_origins(mask.shape)
    fractions = centre_fractions(mask, rows, cols)
    labels = label_from_fraction(fractions)
    for i, r in enumerate(rows):
        for j, c in enumerate(cols):
            share = mask[r + 5 : r + 37, c + 5 : c + 37].mean()
            assert fractions[i, j] == pytest.approx(share)
            assert labels[i, j] == int(share > 0.10)


def test_nodata_makes_a_patch_unusable():
    z = np.zeros((62, 62))
    mask = np.zeros((62, 62), np.uint8)
    assert len(extract_patches(z, z, mask, 0.02)) == 9  # 3 x 3 origins
    pre = z.copy()
    pre[0, 0] = np.nan  # only in the first window
    assert len(extract_patches(pre, z, mask, 0.02)) == 8
    post = z.copy()
    post[61, 61] = np.nan  # only in the last window
    assert len(extract_patches(z, post, mask, 0.02)) == 8
    mask[30, 30] = 255  # in every window
    assert len(extract_patches(z, z, mask, 0.02)) == 0


def test_region_keeps_patches_whose_centre_is_inside():
    region = np.zeros((100, 100), np.uint8)
    region[10:60, 10:60] = 1
    rows, cols = patch_origins(region.shape)
    inside = centres_inside(region, rows, cols)
    for i, r in enumerate(rows):
        for j, c in enumerate(cols):
            assert inside[i, j] == bool(region[r + 5 : r + 37, c + 5 : c + 37].all())
    z = np.zeros((100, 100))
    patches = extract_patches(z, z, np.zeros((100, 100), np.uint8), 0.02, region=region)
    assert sorted(zip(patches.rows.tolist(), patches.cols.tolist(), strict=True)) == [
        (r, c) for r in (10, 20) for c in (10, 20)
    ]


def test_balance_keeps_the_minority_and_samples_the_majority():
    labels = np.array([0] * 50 + [1] * 7 + [0] * 30)
    keep = balance_classes(labels, seed=1)
    assert (labels[keep] == 1).sum() == 7 and (labels[keep] == 0).sum() == 7
    assert set(np.flatnonzero(labels == 1)) <= set(keep)
    np.testing.assert_array_equal(keep, balance_classes(labels, seed=1))
    assert not np.array_equal(keep, balance_classes(labels, seed=2))
