"""The generator benchmark end to end on a tiny hand-made generator (threshold method)."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from tests.detection_bench.tiny_pairs import TinyGenerator, tiny_pair
from worker.commands.bench import bench
from worker.detection_bench import runner
from worker.detection_bench.runner import (
    default_held_out,
    ensure_written,
    format_tables,
    run_generator_benchmark,
)
from worker.pairgen.pair import PairUnavailable
from worker.pipeline import detection_methods
from worker.pipeline.comparison_layout import DETECTIONS_OUTPUT, DetectionMethod
from worker.pipeline.stages import StageSpec
from worker.pipeline.vectorize import VectorizeOptions

TWIN_FALSE_ALARM_BOUND = 500.0  # m2/km2: 1.3 m2 on this 0.0026 km2 pair, < one polygon


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """threshold and a registered method that always raises, on one tiny pair and its twin."""

    def fail(_context, _progress):
        raise RuntimeError("broken on purpose")

    broken = DetectionMethod(
        name="broken",
        summary="Always fails.",
        stage=StageSpec("break", fail, "fails", outputs=(DETECTIONS_OUTPUT,)),
        options_type=VectorizeOptions,
        options_key="broken",
    )
    work = tmp_path_factory.mktemp("bench")
    detection_methods.register_method(broken)
    try:
        lines: list[str] = []
        result = run_generator_benchmark(
            work,
            [TinyGenerator()],
            ["threshold", "broken"],
            [0],
            log=lines.append,
            held_out=["tiny"],
        )
    finally:
        detection_methods.unregister_method("broken")
    result["log"] = lines
    result["work"] = work
    return result


def run_of(report, kind, method):
    (run,) = [r for r in report["runs"] if r["kind"] == kind and r["method"] == method]
    return run


def test_threshold_finds_the_planted_slide(report):
    run = run_of(report, "pair", "threshold")
    assert run["ok"] and run["error"] is None
    (slide,) = run["slides"]
    assert slide["found"]
    assert slide["coverage"] > 0.8
    assert (slide["depth_class"], slide["size_class"], slide["deep_large"]) == (
        ">=3",
        ">=30x30",
        True,
    )
    assert abs(slide["area_error"]) < 0.25
    assert abs(slide["volume_error"]) < 0.25
    assert run["patch"]["f1"] > 0.8
    assert run["seconds"] > 0
    agg = report["aggregates"]["threshold"]
    assert agg["all"]["generators"] == ["tiny"]
    assert agg["all"]["recall_deep_large"] == {"found": 1, "total": 1, "recall": 1.0}
    assert agg["held_out"]["generators"] == ["tiny"]
    assert agg["by_generator"]["tiny"]["f1_median"] == run["patch"]["f1"]
    assert agg["all"]["failures"] == 0
    for kind in ("pair", "twin"):
        assert (report["work"] / "pairs" / "tiny" / "seed0" / kind / "truth.json").exists()
        detections = report["work"] / "runs" / "tiny" / "seed0" / kind / "threshold"
        assert (detections / "detections.geojson").exists()


def test_twin_false_alarms_stay_below_the_bound(report):
    twin = run_of(report, "twin", "threshold")
    assert twin["ok"] and twin["slides"] == []
    assert twin["false_alarm"]["false_alarm_m2_per_km2"] < TWIN_FALSE_ALARM_BOUND
    spread = report["aggregates"]["threshold"]["all"]["twin_false_alarm_m2_per_km2"]
    assert spread["runs"] == 1
    assert spread["worst"] == twin["false_alarm"]["false_alarm_m2_per_km2"]


def test_a_raising_method_is_a_recorded_failure_and_the_run_goes_on(report):
    failed = run_of(report, "pair", "broken")
    assert not failed["ok"]
    assert failed["error"] == "RuntimeError: broken on purpose"
    assert [s["found"] for s in failed["slides"]] == [False]
    assert failed["patch"]["f1"] == 0.0
    agg = report["aggregates"]["broken"]["all"]
    assert agg["failures"] == 2
    assert agg["slides"] == {"found": 0, "total": 1, "recall": 0.0}
    assert agg["twin_false_alarm_m2_per_km2"]["runs"] == 0  # a failed twin flatters nobody
    assert [r["kind"] for r in agg["failed_runs"]] == ["pair", "twin"]
    assert any("FAILED RuntimeError" in line for line in report["log"])
    tables = format_tables(report)
    assert "method broken" in tables and "tiny*" in tables
    broken_table = tables.split("method broken")[1]
    assert broken_table.splitlines()[3].rstrip().endswith("2")  # the fail column
    json.dumps(report["aggregates"], allow_nan=False)


class NoSlidePairs(TinyGenerator):
    """Its pairs with a slide cannot be made (as a flight that fails to reconstruct)."""

    def make(self, seed: int, no_change: bool = False):
        if not no_change:
            raise PairUnavailable("step 2: the reconstruction failed: too few frames")
        return super().make(seed, no_change)


def test_a_pair_that_cannot_be_made_is_reported_and_the_run_goes_on(tmp_path):
    lines: list[str] = []
    report = run_generator_benchmark(
        tmp_path, [NoSlidePairs()], ["threshold"], [0, 1], log=lines.append
    )
    assert report["unavailable_pairs"] == [
        {
            "generator": "tiny",
            "seed": s,
            "kind": "pair",
            "reason": "step 2: the reconstruction failed: too few frames",
        }
        for s in (0, 1)
    ]
    assert [(r["seed"], r["kind"]) for r in report["runs"]] == [(0, "twin"), (1, "twin")]
    assert "tiny seed0 pair: no pair (step 2" in lines[0]
    assert "no pair: tiny seed 1 pair: step 2: the reconstruction failed" in format_tables(report)


def test_unknown_method_is_refused_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="unknown detection method nope"):
        run_generator_benchmark(tmp_path, [TinyGenerator()], ["nope"], [0])
    assert not any(tmp_path.iterdir())


def test_pairs_already_written_are_not_written_again(tmp_path):
    pair = tiny_pair(1)
    folder = tmp_path / "pair"
    assert ensure_written(pair, folder)
    stamp = (folder / "pre.tif").stat().st_mtime_ns
    assert not ensure_written(pair, folder)
    assert (folder / "pre.tif").stat().st_mtime_ns == stamp
    assert not (tmp_path / "pair.part").exists()


def test_held_out_defaults_to_generators_the_scorer_was_not_fitted_to(monkeypatch):
    from worker.pipeline import scorer

    monkeypatch.setattr(scorer, "training_generators", lambda: ("a",))
    assert default_held_out(["a", "b", "c"]) == ["b", "c"]
    monkeypatch.setattr(scorer, "training_generators", lambda: ())
    assert default_held_out(["a", "b"]) == ["a", "b"]


def test_cli_generators_suite_on_the_tiny_generator(tmp_path, monkeypatch):
    monkeypatch.setattr(runner, "available_generators", lambda *_: {"tiny": TinyGenerator()})
    out = tmp_path / "out" / "bench.json"
    args = ["detection", "--generator", "tiny", "--method", "threshold", "--seeds", "1"]
    args += ["--held-out", "tiny", "--work-dir", str(tmp_path / "work"), "--json", str(out)]
    args += ["--speed-size", "600"]
    result = CliRunner().invoke(bench, args)
    assert result.exit_code == 0, result.output
    assert "method threshold" in result.stdout and "tiny*" in result.stdout
    report = json.loads(out.read_text())
    assert report["suite"] == "generators" and report["held_out"] == ["tiny"]
    assert report["aggregates"]["threshold"]["all"]["slides"]["found"] == 1
    assert [p["kind"] for p in report["pairs"]] == ["pair", "twin"]
    assert report["speed"]["size_px"] == 600 and report["speed"]["threshold_km2_per_min"] > 0


def test_cli_refuses_options_of_the_other_suite(tmp_path, monkeypatch):
    monkeypatch.setattr(runner, "available_generators", lambda *_: {"tiny": TinyGenerator()})
    json_path = str(tmp_path / "x.json")
    result = CliRunner().invoke(
        bench, ["detection", "--scenario", "hillslope", "--json", json_path]
    )
    assert result.exit_code == 2 and "--scenario: only with --suite paper" in result.output
    result = CliRunner().invoke(
        bench, ["detection", "--suite", "paper", "--seeds", "2", "--json", json_path]
    )
    assert result.exit_code == 2 and "--seeds: only with --suite generators" in result.output
    result = CliRunner().invoke(bench, ["detection", "--generator", "nope", "--json", json_path])
    assert result.exit_code == 2 and "unknown generator nope" in result.output
    result = CliRunner().invoke(bench, ["detection", "--held-out", "nope", "--json", json_path])
    assert result.exit_code == 2 and "held-out generator nope is not benchmarked" in result.output
