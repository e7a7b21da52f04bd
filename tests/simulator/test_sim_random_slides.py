"""Hillslope runs with random slides (training data) and paper-mounds runs without slides
(no-change surveys)."""

from pathlib import Path

import numpy as np
import pytest

from worker.pipeline.raster_io import read_elevation
from worker.simulator.random_slides import HILLSLOPE_TRAINING_X
from worker.simulator.simulate import SimulationOptions, simulate_scenario


def test_random_slides_replace_the_hillslopes_own_and_keep_away_from_them(tmp_path):
    options = SimulationOptions(
        seed=3, steps=2, random_slides=4, survey="none", write_ortho=False, registration=False
    )
    sim = simulate_scenario("hillslope", tmp_path / "sim", options)
    events = sim.step(2)["events"]
    assert 2 <= len(events) <= 4
    assert all(e["name"].startswith("train-") for e in events)
    for event in events:
        toe_x = event["spec"]["toe_xy"][0]
        assert any(lo <= toe_x <= hi for lo, hi in HILLSLOPE_TRAINING_X)
        assert event["relative_volume_error"] < 1e-6
    mask, _ = read_elevation(sim.truth(2, "mask_since_step1"))
    assert np.count_nonzero(mask == 1) > 1000  # depletion cells at 20 cm


def test_random_slides_exist_on_the_hillslope_only(tmp_path):
    options = SimulationOptions(seed=1, steps=2, random_slides=2, survey="none")
    with pytest.raises(ValueError, match="hillslope scenario only"):
        simulate_scenario("paper-mounds", tmp_path / "sim", options)


def test_no_change_simulation_has_no_landslide_and_only_nuisance(tmp_path: Path):
    options = SimulationOptions(seed=5, steps=2, slides=False, survey="none", write_ortho=False)
    sim = simulate_scenario("paper-mounds", tmp_path / "sim", options)
    assert sim.step(2)["events"] == []
    mask, _ = read_elevation(sim.truth(2, "mask_since_step1"))
    assert np.nansum(mask == 1) + np.nansum(mask == 2) == 0
    before, _ = read_elevation(sim.truth(1))
    after, _ = read_elevation(sim.truth(2))
    change = np.abs(after - before)
    # Lawn growth, wind-blown sand and footprints: centimetres, nothing like a slide.
    assert np.nanpercentile(change, 99.9) < 0.1
