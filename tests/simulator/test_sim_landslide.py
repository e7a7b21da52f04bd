"""Slides conserve volume; masks cover exactly the cells the slides changed."""

import numpy as np
import pytest
from simtest_support import read_raster, short_run

from worker.simulator.evolution import DEPLETION, DEPOSITION, advance
from worker.simulator.georef import Grid
from worker.simulator.landslide import SlideSpec, apply_slide
from worker.simulator.terrain import Scene
from worker.simulator.texture import CONIFER
from worker.simulator.vegetation import make_trees


def _slope_scene(rng) -> Scene:
    grid = Grid.centered(100.0, 100.0, 0.2)
    x, y = grid.mesh()
    # A 30 deg slope rising to the north onto a flat valley floor in the south.
    ground = 100.0 + np.tan(np.radians(30.0)) * np.clip(y + 15.0, 0.0, None)
    ground += 0.05 * np.sin(x / 3.0) * np.cos(y / 4.0)
    tx, ty = np.meshgrid(np.arange(-25.0, 26.0, 5.0), np.arange(-10.0, 31.0, 5.0))
    tx, ty = tx.ravel(), ty.ravel()
    col, row = grid.col_row(tx, ty)
    gz = ground[np.rint(row).astype(int), np.rint(col).astype(int)]
    trees = make_trees(
        tx,
        ty,
        gz,
        np.full(tx.size, 12.0),
        np.full(tx.size, 1.8),
        np.full(tx.size, 7.0),
        CONIFER,
        rng,
    )
    return Scene(
        grid=grid,
        ground=ground,
        surface=np.zeros(grid.shape, np.float32),
        material=np.zeros(grid.shape, np.uint8),
        trees=trees,
        sand_like=np.zeros(grid.shape, bool),
    )


SPEC = SlideSpec(
    name="test",
    toe_xy=(0.0, -5.0),
    azimuth_deg=180.0,
    length_m=20.0,
    width_m=14.0,
    failure_angle_deg=20.0,
    head_angle_deg=55.0,
    flank_angle_deg=45.0,
    runout_m=15.0,
    deposit_angle_deg=6.0,
    deposit_spread=0.8,
    deposit_elongation=1.2,
)


def test_slide_conserves_volume_and_moves_mass_downslope():
    rng = np.random.default_rng(3)
    scene = _slope_scene(rng)
    res = apply_slide(scene.ground, scene.grid, SPEC, rng)
    cell = scene.grid.cell_area
    assert res.depleted_m3 > 200.0
    assert res.relative_volume_error < 1e-9
    assert abs(res.delta.sum() * cell) / res.depleted_m3 < 1e-9
    # Mass leaves the slope and comes to rest further south (downslope).
    assert res.deposit_centroid[1] < res.source_centroid[1] - 10.0
    assert res.max_depth_m > 2.0
    # Changes are either nothing or at least ~ min_change (1 mm): no invisible residue.
    assert np.array_equal(np.abs(res.delta) > 0, res.changed)
    assert res.depletion[res.depletion > 0].min() >= SPEC.min_change_m
    assert res.deposition[res.deposition > 0].min() >= 0.99 * SPEC.min_change_m


def test_step_mask_is_exactly_the_cells_the_slides_changed():
    rng = np.random.default_rng(5)
    scene = _slope_scene(rng)
    before, _ = scene.compose()
    nxt, change = advance(scene, [SPEC], None, rng, dsm_before=before)
    diff = change.dsm_slides_only - before
    assert np.array_equal(change.mask > 0, diff != 0)
    assert np.all(diff[change.mask == DEPLETION] < 0)
    assert np.all(diff[change.mask == DEPOSITION] > 0)
    assert np.all(change.events[change.mask > 0] == 1)
    # Trees rooted on moving ground fell or vanished: none stands on the scar any more.
    assert change.fallen_trees + change.vanished_trees > 0
    res = change.slides[0]
    standing = nxt.trees.kind != 3
    col, row = scene.grid.col_row(nxt.trees.x[standing], nxt.trees.y[standing])
    r = np.rint(row).astype(int) - res.rows.start
    c = np.rint(col).astype(int) - res.cols.start
    ok = (r >= 0) & (r < res.depletion.shape[0]) & (c >= 0) & (c < res.depletion.shape[1])
    assert not np.any(res.depletion[r[ok], c[ok]] > 0)
    # Fallen trees lie in the deposit area, raising the DSM there.
    if change.fallen_trees:
        assert (change.mask == DEPOSITION).sum() > 0


@pytest.fixture(scope="module")
def run():
    return short_run()


def test_each_slide_of_the_scenario_conserves_volume(run):
    vc = run.data["volume_conservation"]
    assert vc["max_relative_error"] < vc["tolerance_relative"] == 1e-6
    events = run.step(2)["events"]
    assert {e["label"] for e in events} == {"mound A", "mound B"}
    dem1, *_ = read_raster(run.truth(1, "dem"))
    dem2, *_ = read_raster(run.truth(2, "dem"))
    ev, *_ = read_raster(run.truth(2, "events"))
    cell = run.data["grid"]["res_m"] ** 2
    for e in events:
        sel = ev == e["index_in_events_raster"]
        net = float((dem2[sel].astype(np.float64) - dem1[sel]).sum()) * cell
        assert e["depleted_m3"] > 0.3
        assert abs(net) / e["depleted_m3"] < 1e-3  # float32 GeoTIFFs
        # Where deposit and scar overlap only the net change shows.
        lowered = float(np.clip(dem1[sel].astype(np.float64) - dem2[sel], 0, None).sum()) * cell
        assert 0.5 * e["depleted_m3"] < lowered <= e["depleted_m3"] * (1 + 1e-3)


def test_scenario_masks_cover_the_changed_cells(run):
    dsm1, *_ = read_raster(run.truth(1, "dsm"))
    dsm2, *_ = read_raster(run.truth(2, "dsm"))
    mask, *_ = read_raster(run.truth(2, "mask"))
    diff = dsm2.astype(np.float64) - dsm1
    assert set(np.unique(mask)) <= {0, 1, 2}
    assert np.all(diff[mask == DEPLETION] < 0)
    assert np.all(diff[mask == DEPOSITION] > 0)
    # Outside the mask only the nuisance changes (footprints, wind-blown sand, lawn).
    assert np.abs(diff[mask == 0]).max() < 0.05
    # ... and they did happen: the detector has something to ignore.
    assert (np.abs(diff[mask == 0]) > 0.005).sum() > 100
    cum, *_ = read_raster(run.truth(2, "mask_since_step1"))
    assert np.array_equal(cum > 0, mask > 0)
