"""Grass mown between surveys is surface change, with the rule on (`vegetation_cut`, off
by default); ground that moved under grass is not.

A mown patch lowers a meadow's surface by the sward's height, past the LoD over square
metres, like a shallow slip. The rule tells them apart by the fine texture: the mown
patch loses the tufts the pre survey saw and gains none, a slip carries its turf along
(new texture where it went, lost where it came from) and leaves a deposit below.
"""

import numpy as np
from scipy import ndimage
from shapely.geometry import box

from tests.pipeline.change_rasters import uniform_change_rasters
from worker.detection_bench.runner import ensure_written, method_options, run_method
from worker.pairgen import GENERATORS
from worker.pipeline.change_regions import (
    LANDSLIDE,
    OBJECTS,
    SURFACE_CHANGE,
    VEGETATION_CUT,
    ChangeRasters,
    Region,
    RegionOptions,
    describe_region,
    label_regions,
    significant_regions,
    split_surface_changes,
)
from worker.pipeline.vectorize import VectorizeOptions, vectorize
from worker.pipeline.vegetation_cut import cut_texture

PIXEL = 0.04
SHAPE = (400, 400)  # 16 x 16 m
SIGMA = 0.05
MOWN = (slice(40, 160), slice(40, 200))  # 4.8 x 6.4 m
SLIP = (slice(220, 340), slice(240, 330))  # 4.8 m down the rows, 3.6 m across
SHIFT_PX = 30  # the slip's turf moved 1.2 m downslope (down the rows)


def _texture(rng: np.random.Generator, corr_px: float) -> np.ndarray:
    field = ndimage.gaussian_filter(rng.normal(size=SHAPE), corr_px)
    return field / field.std()


def _meadow(seed: int, depth_m: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Pre and post DSMs of a furrowed meadow (grass 0.25 m) with a patch mown and a slip
    whose turf slid 1.2 m down the rows, `depth_m` deep at its head and piled at its toe."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]] * PIXEL
    ground = 0.08 * rows + 0.03 * np.sin(2 * np.pi * cols / 0.6)  # furrows 0.6 m apart
    grass_pre = 0.25 * np.clip(1 + 0.35 * _texture(rng, 3.0), 0.2, None)
    grass_post = grass_pre * 1.05 + 0.03 * _texture(rng, 3.0)
    grass_post[MOWN] = 0.045
    ground_post = ground.copy()
    slip = np.zeros(SHAPE, bool)
    slip[SLIP] = True
    head = slip & (np.arange(SHAPE[0])[:, None] < SLIP[0].start + 60)
    toe = slip & ~head
    ground_post[head] -= depth_m
    ground_post[toe] += 0.8 * depth_m
    # The turf moved with the ground: the surface over the slip is the pre surface's
    # texture from upslope.
    moved = np.roll(grass_pre, SHIFT_PX, axis=0)
    grass_post = np.where(slip, moved, grass_post)
    pre = ground + grass_pre + rng.normal(0, 0.01, SHAPE)
    post = ground_post + grass_post + rng.normal(0, 0.01, SHAPE)
    return pre, post


def _rasters(pre: np.ndarray, post: np.ndarray) -> ChangeRasters:
    """The pair's change under one sigma everywhere (SIGMA)."""
    return uniform_change_rasters(pre, post, PIXEL, SIGMA)


def _regions(rasters: ChangeRasters, options: RegionOptions) -> dict[str, list[Region]]:
    """The described regions, by where most of their pixels lie."""
    labels, keep, windows = label_regions(significant_regions(rasters, options), rasters, options)
    out: dict[str, list[Region]] = {"mown": [], "slip": [], "elsewhere": []}
    for label, window in zip(keep, windows, strict=True):
        inside = labels == label
        if inside[MOWN].sum() > inside.sum() / 2:
            where = "mown"
        elif inside[SLIP].sum() > inside.sum() / 2:
            where = "slip"
        else:
            where = "elsewhere"
        out[where].append(describe_region(rasters, labels, label, window, options))
    return out


def test_the_mown_patch_is_a_vegetation_cut_and_the_slip_a_landslide():
    for seed in range(3):
        regions = _regions(_rasters(*_meadow(seed)), RegionOptions(vegetation_cut=True))
        assert regions["mown"], f"seed {seed}: the mowing was not even found"
        assert all(r.kind == SURFACE_CHANGE and r.cause == VEGETATION_CUT for r in regions["mown"])
        mown_area = sum(r.properties["area_m2"] for r in regions["mown"])
        assert mown_area > 0.7 * 4.8 * 6.4, f"seed {seed}: {mown_area:.1f} m2"
        assert regions["slip"] and all(r.kind == LANDSLIDE for r in regions["slip"]), seed
        # Without the rule (the default) the mown patch is a landslide.
        off = _regions(_rasters(*_meadow(seed)), RegionOptions())
        assert off["mown"] and all(r.kind == LANDSLIDE for r in off["mown"])


def test_a_scar_deeper_than_the_grass_stays_a_landslide_even_alone():
    """A 1.5 m deep scar whose deposit ran off the survey: a loss alone under smooth
    stubble-like ground, but ten times deeper than the sward the texture says was there."""
    pre, post = _meadow(5, depth_m=1.5)
    post[SLIP][60:] = pre[SLIP][60:]  # no deposit
    post[MOWN] = pre[MOWN]  # no mowing
    post[SLIP][:60] = ndimage.uniform_filter(post, 15)[SLIP][:60]  # the scar is smooth
    regions = _regions(_rasters(pre, post), RegionOptions(vegetation_cut=True))
    assert regions["slip"] and all(r.kind == LANDSLIDE for r in regions["slip"])


def test_the_texture_figures_tell_mowing_from_turf_that_moved():
    pre, post = _meadow(7)
    dh = post - pre
    mown = np.zeros(SHAPE, bool)
    mown[MOWN] = True
    head = np.zeros(SHAPE, bool)
    head[SLIP[0].start : SLIP[0].start + 60, SLIP[1]] = True
    cut = cut_texture(pre, post, dh, mown, PIXEL, 0.2)
    slid = cut_texture(pre, post, dh, head, PIXEL, 0.2)
    assert cut is not None and slid is not None
    # Mown: the tufts are lost, nothing new; the depth is the sward's, a few sigmas of it.
    assert cut.new_texture_ratio < 0.4  # what is new is the patch edge's step
    assert 1.0 < cut.depth_texture_ratio < 6.0
    # The slip's head: the turf from upslope is new texture, as much as what it lost.
    assert slid.new_texture_ratio > 0.7


def _region(cause: str | None, kind: str, x: float, loss: float, gain: float) -> Region:
    return Region(
        geometry=box(x, 0.0, x + 2.0, 2.0),
        properties={"volume_loss_m3": loss, "volume_gain_m3": gain},
        traits={},
        kind=kind,
        cause=cause,
    )


def test_a_cut_joins_a_landslide_beside_it_only_when_that_holds_its_material():
    options = RegionOptions(vegetation_cut=True)
    scar = _region(VEGETATION_CUT, SURFACE_CHANGE, 0.0, loss=4.0, gain=0.0)
    deposit = _region(None, LANDSLIDE, 3.0, loss=0.0, gain=3.0)  # 1 m away, 3 of 4 m3
    landslides, surface = split_surface_changes([scar, deposit], options)
    assert len(landslides) == 2 and not surface

    speck = _region(None, LANDSLIDE, 3.0, loss=0.0, gain=0.5)  # an eighth of the loss
    landslides, surface = split_surface_changes([scar, speck], options)
    assert len(landslides) == 1 and surface[0].cause == VEGETATION_CUT
    # Lost trees join whatever landslide lies beside them (the crowns a slide took).
    crowns = _region(OBJECTS, SURFACE_CHANGE, 0.0, loss=4.0, gain=0.0)
    landslides, surface = split_surface_changes([crowns, speck], options)
    assert len(landslides) == 2 and not surface


def test_an_agricultural_twin_with_mown_patches_loses_its_false_alarms(tmp_path):
    """agri-shallow's training seed 4, with the rule on: its twin's mown patch is the
    default's largest false alarm; its pair's slide is still found."""
    generator = GENERATORS["agri-shallow"]
    found = {}
    for kind, no_change in (("pair", False), ("twin", True)):
        pair = generator.make(4, no_change=no_change)
        ensure_written(pair, tmp_path / kind)
        for method in ("threshold-cut", "threshold"):
            options = method_options(method, None)
            run = run_method(pair, tmp_path / kind, tmp_path / f"run-{kind}-{method}", options)
            assert run["ok"], run["error"]
            found[kind, method] = run
    with_rule = found["twin", "threshold-cut"]["false_alarm"]["false_alarm_m2_per_km2"]
    without = found["twin", "threshold"]["false_alarm"]["false_alarm_m2_per_km2"]
    assert without > 30_000 and with_rule < 0.15 * without, (with_rule, without)
    slides = [s["found"] for s in found["pair", "threshold-cut"]["slides"]]
    assert slides == [s["found"] for s in found["pair", "threshold"]["slides"]]
    # The stage's result says what it set aside, and how much.
    run = tmp_path / "run-twin-threshold-cut"
    result = vectorize(
        run / "dh.tif",
        run / "significance.tif",
        tmp_path / "again.geojson",
        VectorizeOptions(vegetation_cut=True),
        pre_path=run / "pre_aligned.tif",
        post_path=run / "post_coregistered.tif",
    )
    valid_m2 = found["twin", "threshold-cut"]["false_alarm"]["valid_km2"] * 1e6
    assert result.vegetation_cuts >= 1
    assert result.vegetation_cut_area_m2 > 0.8 * (without - with_rule) * valid_m2 / 1e6
