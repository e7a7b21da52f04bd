"""`slidewatch bench reconstruction --flights N`: conditions from the seed, the summary
per scenario x GNSS mode, and one tiny flight through the command."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
from click.testing import CliRunner

from worker.commands.bench_reconstruction import load_benchmark, reconstruction

flights = load_benchmark("flights")
flights_summary = load_benchmark("flights_summary")


def test_conditions_come_from_the_seed_alone():
    first = [flights.draw_conditions(seed) for seed in range(1, 41)]
    again = [flights.draw_conditions(seed) for seed in range(1, 41)]
    assert first == again
    # Every four consecutive seeds cover both scenarios with both GNSS modes.
    assert {(c.scenario, c.gnss) for c in first[:4]} == {
        (s, g) for s in flights.SCENARIOS for g in flights.GNSS_MODES
    }
    for c in first:
        lo, hi = flights.ALTITUDE_M[c.scenario]
        assert lo <= c.altitude_m <= hi
        assert c.plan in flights.PLANS[c.scenario]
        # A cross pattern flies its path twice: twice the video.
        factor = 2.0 if c.cross_pattern else 1.0
        assert 20.0 * factor <= c.video_seconds <= 30.0 * factor
    assert {c.plan for c in first if c.scenario == "paper-mounds"} == {"lawnmower", "paper-3d"}
    only = flights.draw_conditions(19, scenarios=("hillslope",), video_seconds=(8.0, 8.0))
    assert only.scenario == "hillslope" and only.video_seconds == 8.0


def test_a_run_can_hold_conditions_the_same_for_every_flight():
    """Issue 18's own flights: paper-mounds, RTK, a lawnmower at 7 m, nothing harder, the
    simulator's own render noise; the rest still drawn from the seed as before."""
    from worker.simulator.render import RenderOptions

    fixed = flights.FixedConditions(gnss="rtk", plan="lawnmower", altitude_m=7.0, plain=True)
    for seed in range(1, 21):
        drawn = flights.draw_conditions(seed, ("paper-mounds",), (30.0, 30.0))
        held = flights.draw_conditions(seed, ("paper-mounds",), (30.0, 30.0), fixed)
        assert (held.scenario, held.gnss, held.plan, held.altitude_m) == (
            "paper-mounds",
            "rtk",
            "lawnmower",
            7.0,
        )
        assert held.drawn() == [] and held.video_seconds == 30.0
        assert held.noise_sigma == RenderOptions().noise_sigma
        # Holding one condition leaves the others as the seed draws them.
        only_gnss = flights.draw_conditions(
            seed, ("paper-mounds",), (30.0, 30.0), flights.FixedConditions(gnss="rtk")
        )
        assert only_gnss == replace(drawn, gnss="rtk")
    with pytest.raises(ValueError, match="hillslope flies lawnmower, not paper-3d"):
        flights.draw_conditions(3, ("hillslope",), fixed=flights.FixedConditions(plan="paper-3d"))


def test_each_harder_condition_has_a_block_of_four_seeds_one_per_scenario_and_gnss():
    drawn = {seed: flights.draw_conditions(seed) for seed in range(1, 41)}
    blocks = [*flights.CONDITIONS, None]
    for seed, c in drawn.items():
        expected = blocks[((seed - 1) // 4) % 5]
        assert c.drawn() == ([] if expected is None else [expected])
        assert c.to_dict()["drawn"] == c.drawn()
    low_sun = [c for c in drawn.values() if "low-sun" in c.drawn()]
    assert len(low_sun) == 8 and {(c.scenario, c.gnss) for c in low_sun[:4]} == {
        (s, g) for s in flights.SCENARIOS for g in flights.GNSS_MODES
    }
    for c in low_sun:
        assert 5.0 <= c.sun_elevation_deg <= 15.0 and 0.45 <= c.light_gain <= 0.7
    for c in drawn.values():
        if "texture-poor" in c.drawn():
            assert 0.2 <= c.ground_contrast <= 0.35
        if "rolling-shutter" in c.drawn():
            assert 0.015 <= c.rolling_shutter_s <= 0.035
        if not c.drawn():
            assert (c.sun_elevation_deg, c.light_gain, c.ground_contrast) == (None, 1.0, 1.0)
            assert not c.cross_pattern and c.rolling_shutter_s == 0.0
    # The simulation gets them.
    sim = flights.simulation_options(drawn[13], flights.FlightSettings())
    assert sim.rolling_shutter_s == drawn[13].rolling_shutter_s > 0
    sim = flights.simulation_options(drawn[1], flights.FlightSettings())
    assert sim.cross_pattern and sim.video_seconds == drawn[1].video_seconds


def test_the_summary_groups_flights_by_condition():
    records = [_record(seed, "rtk", float(seed), 1.0, 0.9) for seed in (1, 2, 17)]
    records[0]["conditions"]["drawn"] = ["cross"]
    records[1]["conditions"]["drawn"] = ["cross"]
    records[2]["conditions"]["drawn"] = []
    groups = flights_summary.by_condition(records)
    assert set(groups) == {"cross", "none"}
    assert groups["cross"]["seeds"] == [1, 2] and groups["none"]["seeds"] == [17]
    nmad = groups["cross"]["figures"]["dsm_nmad_as_georeferenced_px"]
    assert (nmad["n"], nmad["median"], nmad["worst"]) == (2, 1.5, 2.0)
    text = flights_summary.condition_table(groups)
    assert "cross: seeds 1, 2; succeeded 2 of 2" in text and "none: seeds 17" in text


def test_rtk_flights_are_georeferenced_with_the_receivers_accuracy():
    rtk = flights.reconstruction_options("slam", "rtk").georef.georef.position_sigma_m
    assert rtk == flights.RTK_SIGMA_M
    assert (
        flights.reconstruction_options("slam", "standalone").georef.georef.position_sigma_m is None
    )
    cond = flights.draw_conditions(2)
    sim = flights.simulation_options(cond, flights.FlightSettings())
    assert (sim.gnss, sim.altitude_m, sim.flight) == (cond.gnss, cond.altitude_m, cond.plan)
    assert sim.render.noise_sigma == cond.noise_sigma


def _record(seed, gnss, nmad_px, coreg_px, completeness, ok=True, ratio=None):
    record = {
        "conditions": {"seed": seed, "scenario": "paper-mounds", "gnss": gnss},
        "success": ok,
    }
    if not ok:
        record["slam"] = {"success": False, "failure": {"kind": "input_error", "message": "x"}}
        return record
    record["slam"] = {
        "success": True,
        "dsm_nmad_as_georeferenced_px": nmad_px,
        "dsm_nmad_coregistered_px": coreg_px,
        "completeness": completeness,
        "real_time_factor_reconstruct": 1.5,
        "real_time_factor_pipeline": 0.8,
        "trajectory": {"rmse_after_similarity_m": 0.01},
        "georeference": {"worst_rms_h_m": 0.05, "all_within_stated_accuracy": True},
    }
    if ratio is not None:
        record["sfm"] = {"success": True, "wall_seconds": 60.0}
        record["sfm_over_slam_wall_time"] = ratio
    return record


def test_summary_gives_median_p90_and_worst_never_the_best():
    records = [
        _record(1, "rtk", 1.0, 0.8, 0.95, ratio=12.0),
        *[_record(s, "rtk", float(s), 1.0, 1.0 - s / 100) for s in range(2, 11)],
        _record(11, "rtk", None, None, None, ok=False),
        _record(12, "standalone", 30.0, 1.5, 0.9),
    ]
    records[-1]["sfm"] = {"success": False, "failure": {"kind": "error", "message": "moved 2 m"}}
    summary = flights_summary.summarize(records)
    assert set(summary) == {"paper-mounds/rtk", "paper-mounds/standalone"}
    rtk = summary["paper-mounds/rtk"]
    assert (rtk["flights"], rtk["succeeded"]) == (11, 10)
    assert rtk["success_pct"] == pytest.approx(90.9)
    assert rtk["failures"] == [{"seed": 11, "kind": "input_error", "message": "x"}]
    nmad = rtk["figures"]["dsm_nmad_as_georeferenced_px"]
    assert (nmad["n"], nmad["median"], nmad["worst"]) == (10, 5.5, 10.0)
    assert nmad["p90"] == pytest.approx(9.1)
    # Completeness: higher is better, so the worst is the smallest.
    assert rtk["figures"]["completeness"]["worst"] == pytest.approx(0.9)
    status = {(t["figure"], t["target"]): t["status"] for t in rtk["targets"]}
    assert status[("success_pct", "all >= 95")] == "not met"
    assert status[("dsm_nmad_as_georeferenced_px", "median <= 2")] == "not met"
    assert status[("dsm_nmad_coregistered_px", "p90 <= 2")] == "met"
    assert status[("sfm_over_slam_wall_time", "median >= 10")] == "met"
    # The whole pipeline's real-time factor (0.8) is judged, not the reconstruction
    # stage's (1.5).
    assert status[("real_time_factor_pipeline", "median >= 1")] == "not met"
    assert ("real_time_factor", "median >= 1") not in status
    # The RTK-only bars are not applied to stand-alone flights; hillslope's not to these.
    standalone = {t["target"] for t in summary["paper-mounds/standalone"]["targets"]}
    assert "median <= 2" not in standalone
    assert all(t["figure"] != "trajectory_rmse_m" for t in rtk["targets"])
    assert rtk["sfm"] == {"runs": 1, "succeeded": 1, "failures": []}
    assert summary["paper-mounds/standalone"]["sfm"]["failures"][0]["seed"] == 12
    text = flights_summary.table(summary)
    assert "paper-mounds/rtk: n=11, succeeded 10 (91 %)" in text
    assert "failed seed 11" in text
    assert "sfm failed seed 12: moved 2 m" in text
    # RTK flights beyond 3 px whose segments all claim the log's accuracy: not told.
    assert rtk["silent_misses"] == [4, 5, 6, 7, 8, 9, 10]
    assert summary["paper-mounds/standalone"]["silent_misses"] == []
    told = "with nothing in the report (within the stated accuracy, heights agreeing)"
    assert f"{told}: seeds 4, 5, 6, 7, 8, 9, 10" in text


def test_a_miss_the_report_tells_is_not_silent():
    told = _record(3, "rtk", 9.0, 1.0, 0.9)
    told["slam"]["georeference"]["all_within_stated_accuracy"] = False
    told["slam"]["quality_passed"] = False
    # Within the log's accuracy, but its dense heights disagree: the report says so too.
    noisy = _record(5, "rtk", 9.0, 1.0, 0.9)
    noisy["slam"]["height_agreement_passed"] = False
    noisy["slam"]["quality_passed"] = False
    summary = flights_summary.summarize([told, _record(4, "rtk", 2.5, 1.0, 0.9), noisy])
    group = summary["paper-mounds/rtk"]
    assert group["silent_misses"] == [] and group["quality_failed"] == [3, 5]
    assert "quality verdict failed: seeds 3, 5" in flights_summary.table(summary)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> tuple[list[str], object, dict]:
    """One tiny flight through the command: its arguments, CLI result and JSON."""
    tmp_path = tmp_path_factory.mktemp("flights")
    out = tmp_path / "flights.json"
    args = ["--flights", "1", "--json", str(out), "--work-dir", str(tmp_path / "work")]
    # Seed 1 draws a cross pattern and stand-alone GPS; --plain and --gnss hold them off.
    args += ["--scenario", "paper-mounds", "--video-seconds", "4", "--sfm-every", "0"]
    args += ["--first-seed", "1", "--gnss", "rtk", "--plan", "lawnmower", "--plain"]
    args += ["--width", "192", "--height", "108", "--fps", "10"]
    result = CliRunner().invoke(reconstruction, args)
    assert result.exit_code == 0, result.output
    return args, result, json.loads(out.read_text())


def test_one_tiny_flight_through_the_command(tiny_run):
    _, result, data = tiny_run
    (flight,) = data["flights"]
    assert flight["conditions"]["seed"] == 1 and flight["conditions"]["video_seconds"] == 4.0
    assert flight["conditions"]["drawn"] == []
    assert (flight["conditions"]["gnss"], flight["conditions"]["plan"]) == ("rtk", "lawnmower")
    assert data["settings"]["fixed"]["plain"] is True
    assert flight["success"] or flight["slam"]["failure"]["message"]
    (key,) = data["summary"]
    assert key == "paper-mounds/rtk"
    assert f"{key}: n=1" in result.output
    assert "dsm_nmad_coregistered_px" in result.output
    assert data["by_condition"]["none"]["seeds"] == [1]
    assert "by condition" in result.output


def test_a_run_from_a_later_stage_reuses_the_reconstructions(tiny_run):
    """`--from-stage georeference` on the work dir of an earlier run: the same
    simulation and reconstruct stage, the later stages run again, no wall time."""
    args, _, first_data = tiny_run
    (first,) = first_data["flights"]
    out = args[args.index("--json") + 1]
    run = Path(args[args.index("--work-dir") + 1]) / "seed0001" / "slam"
    reconstructed = (run / "reconstruct.json").read_bytes()
    georeferenced = (run / "georeference.json").stat().st_mtime_ns
    result = CliRunner().invoke(reconstruction, [*args, "--from-stage", "georeference"])
    assert result.exit_code == 0, result.output
    again = json.loads(Path(out).read_text())
    (flight,) = again["flights"]
    assert again["settings"]["from_stage"] == "georeference"
    assert (run / "reconstruct.json").read_bytes() == reconstructed
    assert (run / "georeference.json").stat().st_mtime_ns > georeferenced
    assert flight["simulation_seconds"] < first["simulation_seconds"]  # not simulated again
    assert flight["slam"]["reused_before"] == "georeference"
    assert flight["slam"]["wall_seconds"] is None
    assert flight["slam"]["real_time_factor_pipeline"] is None
    assert "from georeference on" in result.output
    # The same reconstruction, the same stages: the same figures.
    for key in ("dsm_nmad_as_georeferenced_px", "dsm_nmad_coregistered_px", "completeness"):
        assert flight["slam"][key] == first["slam"][key]
