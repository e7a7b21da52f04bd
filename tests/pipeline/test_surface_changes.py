"""Trees that grow or are felled are surface change; a slide with its trees is a landslide.

A tree-sized region has only a handful of bare-ground pixels around it, and the ground at
a crown's edge reads worse than the error model says (its slope and curvature come from
the mean surface, not from the crown beside it). Counting that ground as moved once it
passes its LoD made growing trees landslides; it counts beyond 1.5 times the LoD. Crowns
a slide carried off are cut from its ground by the LoD: lost within 5 m of it, they join it.
"""

import numpy as np
from scipy import ndimage

from tests.pipeline.change_rasters import uniform_change_rasters
from worker.pipeline.change_regions import (
    DISPLACED_EDGES,
    LANDSLIDE,
    SURFACE_CHANGE,
    BaselineTest,
    ChangeRasters,
    Region,
    RegionOptions,
    describe_region,
    displaced_edges,
    judge_by_baseline,
    label_regions,
    significant_regions,
    split_surface_changes,
)
from worker.pipeline.error_model import LOD_Z

PIXEL = 0.5
SHAPE = (260, 260)
SIGMA = 0.05  # the error model's sigma everywhere
SLIDE = (slice(150, 230), slice(150, 230))  # 40 x 40 m, densely forested


def _crowns(rng: np.random.Generator, centres: list[tuple[int, int]], grow_m: float) -> np.ndarray:
    """Crowns 8-14 m tall, 2.5-3.5 m in radius, their lower half a trunk's height above
    the ground (as the pair generators draw them); `grow_m` is a season's growth."""
    rows, cols = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    height = np.zeros(SHAPE)
    for r, c in centres:
        top = rng.uniform(8.0, 14.0) + grow_m
        radius_px = rng.uniform(2.5, 3.5) / PIXEL
        d = np.hypot(rows - r, cols - c) / radius_px
        height = np.maximum(height, np.where(d <= 1.0, top * (1.0 - 0.5 * d * d), 0.0))
    return height


def _rasters(pre: np.ndarray, post: np.ndarray) -> ChangeRasters:
    """The pair's change under one sigma everywhere (SIGMA)."""
    return uniform_change_rasters(pre, post, PIXEL, SIGMA)


def _forest_pair(seed: int) -> tuple[ChangeRasters, list[tuple[int, int]]]:
    rng = np.random.default_rng(seed)
    # Scattered trees on still ground, dense ones on the slide.
    scattered = [(int(r), int(c)) for r, c in rng.uniform(15, 135, size=(14, 2))]
    dense = [(r, c) for r in range(156, 228, 9) for c in range(156, 228, 9)]
    centres = scattered + dense
    ground = 0.05 * np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]][1] * PIXEL
    tree_seed = int(rng.integers(1 << 30))
    pre_trees = _crowns(np.random.default_rng(tree_seed), centres, 0.0)
    post_trees = _crowns(np.random.default_rng(tree_seed), centres, 0.6)
    slide = np.zeros(SHAPE)
    slide[SLIDE] = -1.2  # the ground and its trees drop together
    # The ground's error; beside a crown it reads 1.6 times worse than the model's sigma.
    near_crown = ndimage.binary_dilation(post_trees > 0.5, iterations=5) & (post_trees <= 0.5)
    error = rng.normal(0.0, SIGMA, SHAPE) * np.where(near_crown, 1.6, 1.0)
    rasters = _rasters(ground + pre_trees, ground + post_trees + slide + error)
    return rasters, scattered


def _kinds(rasters: ChangeRasters, options: RegionOptions) -> tuple[list[str], list[str]]:
    """Kinds of the regions off the slide, and of those on it."""
    labels, keep, windows = label_regions(significant_regions(rasters, options), rasters, options)
    off, on = [], []
    for label, window in zip(keep, windows, strict=True):
        region = describe_region(rasters, labels, label, window, options)
        inside = labels == label
        (on if inside[SLIDE].sum() > inside.sum() / 2 else off).append(region.kind)
    return off, on


def test_growing_trees_are_surface_change_and_a_forested_slide_is_a_landslide():
    options = RegionOptions()
    trees_called_landslides_at_the_lod = 0
    for seed in range(6):
        rasters, scattered = _forest_pair(seed)
        off, on = _kinds(rasters, options)
        assert len(off) >= len(scattered) // 2, f"seed {seed}: the growth was not even found"
        assert off.count(SURFACE_CHANGE) == len(off), f"seed {seed}: {off}"
        assert on == [LANDSLIDE], f"seed {seed}: {on}"
        at_lod, on_at_lod = _kinds(rasters, RegionOptions(ground_motion_lod_ratio=1.0))
        assert on_at_lod == [LANDSLIDE]
        trees_called_landslides_at_the_lod += at_lod.count(LANDSLIDE)
    # What the rule is for: at the LoD itself, the crowns' ground passes by chance.
    assert trees_called_landslides_at_the_lod >= 3


def test_trees_a_debris_flow_took_are_part_of_it_and_other_tree_change_is_not():
    """Crowns the channel took are cut off from it by the LoD; lost within 5 m of it, they
    join it. Trees that grew beside it, or were felled far off, stay surface change."""
    rng = np.random.default_rng(11)
    ground = 0.05 * np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]][1] * PIXEL
    channel = (slice(40, 220), slice(120, 136))  # 90 m long, 8 m wide, scoured 1 m
    taken = [(r, 108) for r in range(50, 215, 25)]  # 6 m off its left bank
    grown = [(r, 148) for r in range(50, 215, 25)]  # 6 m off its right bank
    far = [(r, 30) for r in range(40, 230, 30)]  # felled 42 m away
    tree_seed = int(rng.integers(1 << 30))
    pre_trees = _crowns(np.random.default_rng(tree_seed), grown + taken + far, 0.0)
    post_trees = _crowns(np.random.default_rng(tree_seed), grown, 1.0)
    post = ground + post_trees + rng.normal(0.0, SIGMA, SHAPE)
    post[channel] -= 1.0
    rasters = _rasters(ground + pre_trees, post)
    options = RegionOptions()
    labels, keep, windows = label_regions(significant_regions(rasters, options), rasters, options)
    regions = [
        describe_region(rasters, labels, label, window, options)
        for label, window in zip(keep, windows, strict=True)
    ]
    landslides, surface = split_surface_changes(regions, options)

    def column(region: Region) -> float:
        return (region.geometry.centroid.x - 500000) / PIXEL

    left = [r for r in regions if 95 < column(r) < 118]
    right = [r for r in regions if 138 < column(r) < 160]
    assert len(left) == len(taken) and len(right) == len(grown), "one region per crown"
    assert all(r.kind == SURFACE_CHANGE for r in left + right)  # each alone looks like trees
    assert sorted(column(r) for r in landslides) == sorted(
        column(r) for r in regions if 95 < column(r) < 138
    )
    assert len(landslides) == len(taken) + 1  # the channel and the crowns it took
    assert len(surface) == len(grown) + len(far)
    # Without the context only the channel is a landslide.
    alone, _ = split_surface_changes(regions, RegionOptions(object_context_m=0.0))
    assert len(alone) == 1


def _judged(rasters: ChangeRasters, options: RegionOptions) -> tuple[list[str], list[str]]:
    """Kinds of the regions before and after they are judged on the baseline's regions."""
    labels, keep, windows = label_regions(significant_regions(rasters, options), rasters, options)
    regions = [
        describe_region(rasters, labels, k, w, options) for k, w in zip(keep, windows, strict=True)
    ]
    judged = judge_by_baseline(rasters, labels, keep, windows, regions, options)
    return [r.kind for r in regions], [r.kind for r in judged]


def test_a_region_the_baseline_sets_aside_as_trees_is_set_aside():
    """A clump of trees gone in the post survey, beside a strip of ground that one survey
    got wrong: the per-pixel LoD (high on the canopy's rough ground) keeps only the
    clump's edge, which with the strip reads as ground motion; the baseline's region
    takes in the whole clump and is trees lost with little ground moved around them."""
    rng = np.random.default_rng(5)
    pre = rng.normal(0.0, SIGMA, SHAPE)
    post = rng.normal(0.0, SIGMA, SHAPE)
    pre[40:60, 40:60] += 15.0
    post[40:60, 60:63] -= 0.6
    rasters = _rasters(pre, post)
    rasters.lod = rasters.lod.copy()
    rasters.lod[40:60, 40:58] = 30.0
    rasters.significance[40:60, 40:58] = 0  # NO_CHANGE under the canopy's LoD
    options = RegionOptions()
    assert _judged(rasters, options)[0] == [LANDSLIDE]  # judged alone
    rasters.baseline = BaselineTest(0.0, LOD_Z * SIGMA)  # median, LoD95 of one NMAD
    assert _judged(rasters, options)[1] == [SURFACE_CHANGE]


def test_a_forested_slide_stays_a_landslide_when_judged_on_the_baseline():
    options = RegionOptions()
    for seed in range(3):
        rasters, _ = _forest_pair(seed)
        rasters.baseline = BaselineTest(0.0, LOD_Z * SIGMA)
        before, after = _judged(rasters, options)
        assert before == after, f"seed {seed}"
        assert LANDSLIDE in after


def test_crowns_a_slide_took_join_it_as_far_as_the_baseline_joins_them():
    """A slide's ground part and the clump of crowns it carried off, 7 m apart in the
    default's regions: between them ground dropped 0.3 m, beyond the baseline's one LoD
    but under a per-pixel LoD raised there (steep, rough ground). Judged alone the crowns
    are felling, beyond the 5-m context; the baseline's region takes in both, so judged
    on it the crowns join the slide, as the baseline's own rule joins them."""
    rng = np.random.default_rng(7)
    pre = rng.normal(0.0, SIGMA, SHAPE)
    post = rng.normal(0.0, SIGMA, SHAPE)
    ground_part = (slice(100, 160), slice(40, 100))  # 30 x 30 m, dropped 1.5 m
    strip = (slice(100, 160), slice(100, 114))  # 7 m of ground dropped 0.3 m
    crowns = (slice(100, 160), slice(114, 130))  # a clump of crowns 12 m tall, gone
    post[ground_part] -= 1.5
    post[strip] -= 0.3
    pre[crowns] += 12.0
    rasters = _rasters(pre, post)
    rasters.lod = rasters.lod.copy()
    rasters.lod[strip] = 1.0
    rasters.significance[strip] = 0  # NO_CHANGE under the raised LoD
    options = RegionOptions()
    labels, keep, windows = label_regions(significant_regions(rasters, options), rasters, options)
    regions = [
        describe_region(rasters, labels, k, w, options) for k, w in zip(keep, windows, strict=True)
    ]
    assert sorted(r.kind for r in regions) == [LANDSLIDE, SURFACE_CHANGE]
    gap = next(r.geometry for r in regions if r.kind == LANDSLIDE).distance(
        next(r.geometry for r in regions if r.kind == SURFACE_CHANGE)
    )
    assert 6.5 <= gap <= 7.5 and gap > options.object_context_m
    alone, _ = split_surface_changes(regions, options)
    assert len(alone) == 1  # the crowns read as felling

    rasters.baseline = BaselineTest(0.0, LOD_Z * SIGMA)
    judged = judge_by_baseline(rasters, labels, keep, windows, regions, options)
    landslides, surface = split_surface_changes(judged, options)
    assert len(landslides) == 2 and not surface
    # Measured from the default's own regions, as before: the crowns stay felling.
    own = judge_by_baseline(rasters, labels, keep, windows, regions, options, context=False)
    assert len(split_surface_changes(own, options)[0]) == 1


def _house_pair(seed: int, slid: tuple[slice, slice] | None) -> ChangeRasters:
    """A 24 x 12 m house 12 m tall on 0.3 m pixels, its walls in the post survey
    resampled 0.1-0.15 pixel off (a registration's residual, a rotation's correction);
    the ground in `slid` lowered 1 m in the post survey."""
    pixel, shape = 0.3, (200, 200)
    rng = np.random.default_rng(seed)
    ground = 0.02 * np.mgrid[0 : shape[0], 0 : shape[1]][1] * pixel
    house = np.zeros(shape)
    house[60:140, 70:110] = 12.0
    post = ground + ndimage.shift(house, (0.1, 0.15), order=3, mode="nearest")
    post += rng.normal(0.0, SIGMA, shape)
    if slid is not None:
        post[slid] -= 1.0
    pre = ground + house + rng.normal(0.0, SIGMA, shape)
    return uniform_change_rasters(pre, post, pixel, SIGMA)


def _described(rasters: ChangeRasters, options: RegionOptions) -> list[Region]:
    labels, keep, windows = label_regions(significant_regions(rasters, options), rasters, options)
    return [
        describe_region(rasters, labels, label, window, options)
        for label, window in zip(keep, windows, strict=True)
    ]


def test_a_walls_edge_resampled_a_fraction_of_a_pixel_off_is_surface_change():
    """The house's walls resampled a fraction of a pixel off: a thin strip of metres of
    change along them, half of it beside the house rather than on it (the blur is under
    the object height), so the object rule alone would take it for ground that moved.
    Each survey's height there lies within the other's over a pixel's neighbourhood:
    surface change. Ground lowered a metre along the same wall lies below its neighbours
    before: a landslide."""
    options = RegionOptions()
    for seed in range(3):
        for slid in (None, (slice(70, 130), slice(110, 150))):  # 18 x 12 m along the wall
            regions = _described(_house_pair(seed, slid), options)
            assert len(regions) == 1, f"seed {seed}: the walls' strip is one region"
            (region,) = regions
            if slid:
                assert region.kind == LANDSLIDE, f"seed {seed}"
                assert region.properties["volume_loss_m3"] > 150.0
            else:
                assert region.traits["object_share"] < options.object_fraction
                assert region.kind == SURFACE_CHANGE, f"seed {seed}"


def test_displaced_edges_explain_a_blurred_step_and_not_a_scar():
    pre = np.zeros((9, 9), np.float32)
    pre[:, :4] = 10.0  # a wall between columns 3 and 4
    post = pre.copy()
    post[:, 4] = 2.0  # the wall's foot blurred by resampling
    post[6:, 6:] -= 1.0  # a scar on the ground beyond it
    lod = np.full(pre.shape, 0.2, np.float32)
    explained = displaced_edges(pre, post - pre, lod)
    assert explained[:, 4].all()
    assert not explained[7:, 7:].any()  # below the lowest of its neighbours before
    dh = post - pre
    dh[0, 0] = np.nan
    assert not displaced_edges(pre, dh, lod)[0, 0]


def test_a_walls_displaced_edge_beside_a_slide_does_not_join_it():
    """The wall's strip of the test above, a slide 3 m off: the strip stays surface
    change (a lost object there would join the slide as what it carried off)."""
    options = RegionOptions()
    # 18 x 12 m, its edge 3 m east of the wall.
    regions = _described(_house_pair(0, (slice(70, 130), slice(120, 160))), options)
    assert sorted(r.kind for r in regions) == [LANDSLIDE, SURFACE_CHANGE]
    (strip,) = [r for r in regions if r.kind == SURFACE_CHANGE]
    assert strip.cause == DISPLACED_EDGES
    landslides, surface = split_surface_changes(regions, options)
    assert len(landslides) == 1 and surface == [strip]
    assert landslides[0].properties["area_m2"] < 18 * 12 * 1.2
