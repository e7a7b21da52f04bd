"""A region's edge drawn by the simple baseline's test (change_regions.grow_into_baseline):
a change found by the per-pixel LoD keeps the edge its steep flank hides from that LoD
but not from the baseline's, and no change the per-pixel LoD did not find is added."""

import numpy as np

from tests.pipeline.change_rasters import change_rasters, uniform_error_model
from worker.pipeline.change_regions import (
    BaselineTest,
    describe_region,
    grow_into_baseline,
    label_regions,
    significant_regions,
)
from worker.pipeline.error_model import LOD_Z
from worker.pipeline.vectorize import VectorizeOptions

PIXEL_M = 0.1
SIGMA_M = 0.025  # the raster's one NMAD: the baseline's LoD95 is 0.049 m
STEEP_LOD_M = 0.1  # the per-pixel LoD on the steep ring


def _scarp(seed: int, with_slide: bool = True):
    """A 200 x 200 raster: a slide whose core (radius 20 px) lost 0.5 m and whose ring
    out to 23 px, on steep ground, lost 0.07 m (past the baseline's LoD, not past the
    ring's own); a separate 10 x 10 patch of 0.07 m on steep ground off to the side;
    noise elsewhere."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:200, 0:200]
    radius = np.hypot(rows - 100, cols - 100)
    dh = rng.normal(0, 0.005, (200, 200)).astype(np.float32)
    lod = np.full((200, 200), LOD_Z * SIGMA_M, np.float32)
    ring = (radius >= 20) & (radius < 23)
    lod[(radius >= 18) & (radius < 26)] = STEEP_LOD_M
    if with_slide:
        dh[radius < 20] -= 0.5
        dh[ring] -= 0.07
    lod[15:35, 15:35] = STEEP_LOD_M
    dh[20:30, 20:30] -= 0.07  # a patch on steep ground only the baseline finds
    model = uniform_error_model(PIXEL_M, SIGMA_M, dh.size)
    rasters = change_rasters(dh, lod, model, PIXEL_M)
    rasters.baseline = BaselineTest(0.0, LOD_Z * SIGMA_M)
    return rasters, radius < 23


def _regions(rasters, fringe_px: int):
    options = VectorizeOptions(baseline_fringe_px=fringe_px, min_area_m2=1.0)
    labels, keep, windows = label_regions(significant_regions(rasters, options), rasters, options)
    if fringe_px:
        labels, windows = grow_into_baseline(labels, keep, rasters, fringe_px, options)
    return (
        labels,
        keep,
        [
            describe_region(rasters, labels, k, w, options)
            for k, w in zip(keep, windows, strict=True)
        ],
    )


def test_the_edge_the_steep_lod_hid_is_drawn_by_the_baseline():
    for seed in (1, 2, 3):
        rasters, truth = _scarp(seed)
        true_area = truth.sum() * PIXEL_M**2
        labels, keep, regions = _regions(rasters, 0)
        assert len(regions) == 1
        assert regions[0].properties["area_m2"] < 0.85 * true_area  # the core only
        labels, keep, regions = _regions(rasters, VectorizeOptions().baseline_fringe_px)
        assert len(regions) == 1
        assert abs(regions[0].properties["area_m2"] / true_area - 1) < 0.03
        found = labels == keep[0]
        assert (found & truth).sum() / truth.sum() > 0.98
        # The patch only the baseline finds stays out: growth adds no region.
        assert not found[15:35, 15:35].any()


def test_growth_is_bounded_and_adds_nothing_without_a_region():
    rasters, _ = _scarp(4, with_slide=False)
    labels, keep, regions = _regions(rasters, 3)
    assert regions == [] and not labels.any()
    # A baseline-significant band reaching far from a region is followed for at most
    # the given pixels.
    rasters, _ = _scarp(5)
    # A band 3 pixels wide across steep ground, past the baseline's LoD only.
    rasters.dh[99:102, :] -= 0.07
    rasters.lod[99:102, :] = STEEP_LOD_M
    labels, keep, _ = _regions(rasters, 3)
    assert len(keep) == 1
    cols = np.flatnonzero((labels == keep[0])[100])
    assert cols.min() >= 100 - 23 - 3 and cols.max() <= 100 + 23 + 3
