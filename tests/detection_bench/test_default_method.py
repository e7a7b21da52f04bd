"""The default method, and the scored method, on ground never tuned on.

Fixtures from two generators outside the shipped scorer's training and calibration (its
card's held-out generators, and the survey simulator's analytic pairs, which no scorer
ever sees), at benchmark seeds (the scorer trains on seeds from 0): each planted slide
is found, and the no-change twin of the same seed gives no detection at all.
"""

import pytest

from worker.detection_bench.runner import ensure_written, run_method
from worker.detection_bench.simulator_pairs import SimulatorPairs
from worker.pairgen import GENERATORS
from worker.pipeline.comparison import ComparisonOptions, default_method
from worker.pipeline.scorer import load_scorer, training_generators

FIXTURES = [("fractal-forest", 1000), (SimulatorPairs().name, 1001)]


def _generator(name: str):
    return GENERATORS[name] if name in GENERATORS else SimulatorPairs()


def test_the_fixtures_are_held_out_from_the_shipped_scorer():
    fitted = set(training_generators())
    assert fitted and all(name not in fitted for name, _ in FIXTURES)
    assert "fractal-forest" in load_scorer().card["held_out_generators"]


@pytest.mark.parametrize("method", [default_method(), "scored"])
@pytest.mark.parametrize(("name", "seed"), FIXTURES)
def test_finds_the_slides_and_nothing_on_the_twin(tmp_path, name, seed, method):
    generator = _generator(name)
    options = ComparisonOptions(method=method)
    pair = generator.make(seed)
    ensure_written(pair, tmp_path / "pair")
    run = run_method(pair, tmp_path / "pair", tmp_path / "run-pair", options)
    assert run["ok"], run["error"]
    assert run["slides"] and all(s["found"] for s in run["slides"]), run["slides"]
    assert run["patch"]["f1"] >= 0.8

    twin = generator.make(seed, no_change=True)
    ensure_written(twin, tmp_path / "twin")
    run = run_method(twin, tmp_path / "twin", tmp_path / "run-twin", options)
    assert run["ok"], run["error"]
    assert run["detections"] == 0 and run["false_alarm"]["false_alarm_m2"] == 0.0
