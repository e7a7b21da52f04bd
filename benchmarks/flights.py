"""Reconstruction over many simulated flights: `slidewatch bench reconstruction --flights N`.

Flight i (seed = first seed + i) draws its conditions from its seed alone
(`draw_conditions`), so a flight is the same flight in every run and on every machine:

- scenario: paper-mounds or hillslope (alternating in pairs of seeds, or `--scenario`);
- GNSS: stand-alone or RTK, alternating with the seed so that every scenario has both;
- flight plan: what the scenario flies (paper-mounds: lawnmower or the paper's 3-D path;
  hillslope: a terrain-following lawnmower);
- altitude: paper-mounds 5-20 m (the 3-D path: its low end 5-10 m, rising to 20 m);
  hillslope 60-150 m;
- video length (default 20-30 s): the simulator flies the whole plan in that time, so it
  sets the speed (reported per flight as flown, with whether 20 m/s was not enough);
- sensor noise (render noise sigma 0.8-3.0 levels: dim light raises it);
- one harder condition per block of four seeds (one flight per scenario x GNSS mode),
  in turn: seeds 1-4 a cross pattern (the plan flown again with perpendicular lines;
  the video is then twice the drawn length, as the path is twice as long), 5-8 low sun
  (elevation 5-15 deg instead of 38-62: long shadows, and the light 0.45-0.7 of the
  usual), 9-12 a texture-poor field (the ground's contrast 0.2-0.35 of the usual: mown
  grass), 13-16 a rolling shutter (rows read over 15-35 ms, at most 33 ms: the frame at
  30 fps), 17-20 none; then again
  from 21. One at a time, so that a change is told by its condition, with every
  scenario and GNSS mode under each; the values come from a stream of their own, so
  the draws above are what they were before these conditions existed;
- the simulation seed itself: terrain, texture, sun (azimuth, elevation 38-62 deg),
  exposure, the GNSS and attitude error realisations.

A run can hold some of these the same for every flight (`FixedConditions`: `--gnss`,
`--plan`, `--altitude`, and `--plain` for no harder condition and the simulator's own
render noise, as `slidewatch simulate` flies by default); the rest is drawn as above.
Issue 18's own flights are `--flights 8 --scenario paper-mounds --gnss rtk --plan
lawnmower --altitude 7 --plain --video-seconds 30`.

Each flight is simulated (one survey, 640x360 video, RTK or stand-alone logs), then
reconstructed with `slam` as a user would (for RTK logs with the receiver's stated
accuracy, 2 / 2 / 4 cm). Recorded per flight: success or the failure's reason (the
pipeline's refusal or error, or a DSM too far off to co-register onto its truth), DSM
NMAD against the truth DSM as georeferenced and after shift + tilt co-registration
(metres and DSM pixels), completeness, trajectory RMSE (after the best similarity, and
as georeferenced), the georeferencing residuals of georeference.json and whether each
segment is within the log's stated accuracy, stage times, real-time factor; every
`--sfm-every`th flight also with `sfm`, for the sfm / slam wall-time ratio.
benchmarks/flights_summary.py summarises them per scenario and GNSS mode.

A change to the stages after the reconstruct stage is measured on the same
reconstructions with `--from-stage georeference` (or dsm, orthophoto) on an earlier
run's work dir: the simulations and the reconstruct stage are reused, the later stages
run again, and the wall-time figures are left out (minutes for a run of flights that
took hours).
"""

from __future__ import annotations

import json
import math
import shutil
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from dsm_truth import coregistered_error, dsm_errors, read_truth_trajectory, trajectory_errors

from worker.pipeline.errors import InputError
from worker.pipeline.reconstruction import (
    STAGES,
    ReconstructionInputs,
    ReconstructionOptions,
    reconstruct_survey,
)
from worker.simulator.manifest import Manifest
from worker.simulator.render import RenderOptions
from worker.simulator.simulate import SimulationOptions, rng_for, simulate_scenario

SCENARIOS = ("paper-mounds", "hillslope")
GNSS_MODES = ("standalone", "rtk")
# The receiver's stated 1-sigma accuracy (east, north, up) of an RTK fix, as a user
# passes it for logs that do not state it (GeorefOptions.position_sigma_m).
RTK_SIGMA_M = (0.02, 0.02, 0.04)
PLANS = {"paper-mounds": ("lawnmower", "paper-3d"), "hillslope": ("lawnmower",)}
ALTITUDE_M = {"paper-mounds": (5.0, 20.0), "hillslope": (60.0, 150.0)}
# paper-3d climbs from its altitude to 20 m: its low end stays well below that.
PAPER_3D_ALTITUDE_M = (5.0, 10.0)
NOISE_SIGMA = (0.8, 3.0)
# The harder conditions (see the module doc), one per block of four seeds in this order,
# then a block without any; and their ranges.
LOW_SUN_ELEVATION_DEG = (5.0, 15.0)
LOW_SUN_LIGHT_GAIN = (0.45, 0.7)
TEXTURE_POOR_CONTRAST = (0.2, 0.35)
ROLLING_SHUTTER_S = (0.015, 0.035)
MAX_READOUT_S = 0.033
CONDITIONS = ("cross", "low-sun", "texture-poor", "rolling-shutter")


@dataclass(frozen=True)
class FlightConditions:
    """What one flight's seed decides."""

    seed: int
    scenario: str
    gnss: str
    plan: str
    altitude_m: float
    video_seconds: float
    noise_sigma: float
    cross_pattern: bool = False
    sun_elevation_deg: float | None = None  # None: the simulator's own draw, 38-62 deg
    light_gain: float = 1.0
    ground_contrast: float = 1.0
    rolling_shutter_s: float = 0.0

    def drawn(self) -> list[str]:
        """The harder conditions (CONDITIONS) this flight has."""
        have = {
            "cross": self.cross_pattern,
            "low-sun": self.sun_elevation_deg is not None,
            "texture-poor": self.ground_contrast < 1.0,
            "rolling-shutter": self.rolling_shutter_s > 0.0,
        }
        return [name for name in CONDITIONS if have[name]]

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "drawn": self.drawn()}


@dataclass(frozen=True)
class FlightSettings:
    """What is the same for every flight of a run."""

    width: int = 640
    height: int = 360
    fps: float = 30.0
    video_seconds: tuple[float, float] = (20.0, 30.0)
    render_workers: int = 1
    # A rolling-shutter flight's readout time is given to the pipeline, as a user who
    # knows their camera gives it (False: not given, the shutter not modelled).
    readout_given: bool = True
    # Reuse each flight's reconstruction from an earlier run in the same work dir and
    # run the stages from this one on (after a change to them: the same reconstructions,
    # before and after); a flight without one is reconstructed whole. None: every stage.
    from_stage: str | None = None


# What is given to the pipeline, not to the simulator: a change of these reuses the
# simulations.
_PIPELINE_SETTINGS = ("readout_given", "from_stage")


@dataclass(frozen=True)
class FixedConditions:
    """What a run holds the same for every flight instead of drawing it from the seed
    (None: drawn). `plain`: no harder condition, and the simulator's own render noise."""

    gnss: str | None = None
    plan: str | None = None
    altitude_m: float | None = None
    plain: bool = False
    rolling_shutter_s: float | None = None  # every flight's readout (0: a global shutter)


def draw_conditions(
    seed: int,
    scenarios: tuple[str, ...] = SCENARIOS,
    video_seconds: tuple[float, float] = (20.0, 30.0),
    fixed: FixedConditions | None = None,
) -> FlightConditions:
    """The conditions of the flight with this seed. Scenario and GNSS mode cycle with
    the seed (every four consecutive seeds cover both scenarios x both modes); the rest
    is drawn from the seed's own random stream. What `fixed` holds replaces the draw;
    every value is drawn all the same, so that the others stay what they were."""
    fixed = fixed or FixedConditions()
    scenario = scenarios[((seed - 1) // 2) % len(scenarios)]
    gnss = fixed.gnss or GNSS_MODES[(seed - 1) % 2]
    rng = rng_for(seed, "bench-flight-conditions")
    plan = str(rng.choice(PLANS[scenario]))
    plan = fixed.plan or plan
    if plan not in PLANS[scenario]:
        raise ValueError(f"{scenario} flies {' or '.join(PLANS[scenario])}, not {plan}")
    lo, hi = PAPER_3D_ALTITUDE_M if plan == "paper-3d" else ALTITUDE_M[scenario]
    altitude = round(float(rng.uniform(lo, hi)), 1)
    base = FlightConditions(
        seed=seed,
        scenario=scenario,
        gnss=gnss,
        plan=plan,
        altitude_m=altitude if fixed.altitude_m is None else fixed.altitude_m,
        video_seconds=round(float(rng.uniform(*video_seconds)), 1),
        noise_sigma=round(float(rng.uniform(*NOISE_SIGMA)), 2),
    )
    if fixed.plain:
        drawn = replace(base, noise_sigma=RenderOptions().noise_sigma)
    else:
        drawn = _harder(base, rng_for(seed, "bench-flight-harder-conditions"))
    if fixed.rolling_shutter_s is not None:
        if not 0.0 <= fixed.rolling_shutter_s <= MAX_READOUT_S:
            raise ValueError(
                f"a rolling shutter's readout is 0 to {MAX_READOUT_S * 1000:.1f} ms at the "
                f"benchmark's frame rate, not {fixed.rolling_shutter_s * 1000:g} ms"
            )
        drawn = replace(drawn, rolling_shutter_s=fixed.rolling_shutter_s)
    return drawn


def _harder(base: FlightConditions, rng: np.random.Generator) -> FlightConditions:
    """`base` with the harder condition of its block of seeds (see the module doc);
    every value is drawn whatever the condition, so that they do not shift one
    another."""
    per_block = len(GNSS_MODES) * len(SCENARIOS)
    block = ((base.seed - 1) // per_block) % (len(CONDITIONS) + 1)
    on = {name: block == i for i, name in enumerate(CONDITIONS)}
    elevation = round(float(rng.uniform(*LOW_SUN_ELEVATION_DEG)), 1)
    gain = round(float(rng.uniform(*LOW_SUN_LIGHT_GAIN)), 2)
    contrast = round(float(rng.uniform(*TEXTURE_POOR_CONTRAST)), 2)
    # The readout must end within the frame (33.3 ms at the benchmark's 30 fps): the
    # draws beyond it (seed 53: 34.9 ms) are read as the longest the frame allows.
    readout = min(round(float(rng.uniform(*ROLLING_SHUTTER_S)), 4), MAX_READOUT_S)
    return replace(
        base,
        cross_pattern=bool(on["cross"]),
        # The cross pattern flies the path twice: twice the video at the same speed.
        video_seconds=base.video_seconds * 2 if on["cross"] else base.video_seconds,
        sun_elevation_deg=elevation if on["low-sun"] else None,
        light_gain=gain if on["low-sun"] else 1.0,
        ground_contrast=contrast if on["texture-poor"] else 1.0,
        rolling_shutter_s=readout if on["rolling-shutter"] else 0.0,
    )


def simulation_options(cond: FlightConditions, settings: FlightSettings) -> SimulationOptions:
    """One step, one video survey, no extra truth products: only what the flight needs."""
    return SimulationOptions(
        seed=cond.seed,
        steps=1,
        survey="video",
        video_seconds=cond.video_seconds,
        width=settings.width,
        height=settings.height,
        fps=settings.fps,
        flight=cond.plan,
        altitude_m=cond.altitude_m,
        gnss=cond.gnss,
        registration=False,
        write_ortho=False,
        workers=settings.render_workers,
        render=replace(RenderOptions(), noise_sigma=cond.noise_sigma),
        cross_pattern=cond.cross_pattern,
        sun_elevation_deg=cond.sun_elevation_deg,
        light_gain=cond.light_gain,
        ground_contrast=cond.ground_contrast,
        rolling_shutter_s=cond.rolling_shutter_s,
    )


def reconstruction_options(method: str, gnss: str, readout_s: float = 0.0) -> ReconstructionOptions:
    """The options a user gives: the method, for RTK logs the receiver's accuracy, and
    for a rolling-shutter camera its readout time (as its maker or a measurement gives
    it)."""
    options = ReconstructionOptions(method=method)
    if gnss == "rtk":
        options.georef.georef.position_sigma_m = RTK_SIGMA_M
    if readout_s > 0:
        options.camera.readout_ms = readout_s * 1000.0
    return options


def run_flight(
    cond: FlightConditions, work: Path, settings: FlightSettings, with_sfm: bool
) -> dict[str, Any]:
    """Simulate and reconstruct one flight; its record (see the module doc). The
    simulation is kept in `work` and reused when the conditions are the same."""
    sim_dir = work / "sim"
    stamp = work / "conditions.json"
    # What the simulation depends on (not what is given to the pipeline).
    simulated = {k: v for k, v in asdict(settings).items() if k not in _PIPELINE_SETTINGS}
    wanted = json.dumps({"conditions": cond.to_dict(), "settings": simulated})
    start = time.perf_counter()
    cached = (sim_dir / "manifest.json").is_file() and stamp.is_file()
    if not cached or stamp.read_text() != wanted:
        shutil.rmtree(sim_dir, ignore_errors=True)
        simulate_scenario(cond.scenario, sim_dir, simulation_options(cond, settings))
        stamp.write_text(wanted)
    record: dict[str, Any] = {
        "conditions": cond.to_dict(),
        "simulation_seconds": round(time.perf_counter() - start, 1),
    }
    manifest = Manifest.load(sim_dir / "manifest.json")
    survey = manifest.steps[0]["surveys"][0]
    record["flight"] = _flown(survey)
    readout = (
        float((survey.get("rolling_shutter") or {}).get("readout_s", 0.0))
        if settings.readout_given
        else 0.0
    )
    slam = _reconstruct(
        manifest, survey, work / "slam", "slam", cond.gnss, readout, settings.from_stage
    )
    record["slam"] = slam
    record["success"] = slam["success"]
    if with_sfm:
        sfm = _reconstruct(
            manifest, survey, work / "sfm", "sfm", cond.gnss, readout, settings.from_stage
        )
        kept = ("success", "failure", "wall_seconds", "quality_passed")
        record["sfm"] = {k: sfm[k] for k in kept if k in sfm}
        record["sfm"]["dsm_nmad_as_georeferenced_px"] = sfm.get("dsm_nmad_as_georeferenced_px")
        if slam["success"] and sfm["success"] and slam["wall_seconds"] and sfm["wall_seconds"]:
            record["sfm_over_slam_wall_time"] = round(sfm["wall_seconds"] / slam["wall_seconds"], 2)
    return record


def _flown(survey: dict[str, Any]) -> dict[str, Any]:
    """What the simulator flew: the speed follows from the plan and the video length."""
    flight = survey["flight"]
    return {
        "speed_m_s": flight["speed_m_s"],
        "truncated_by_max_speed": flight.get("truncated_by_max_speed"),
        "lines": flight["lines"],
        "line_spacing_m": flight["line_spacing_m"],
        "side_overlap": flight["plan"]["side_overlap"],
        "altitude_range_m": flight.get("altitude_range_m"),
        "cross_grid_flown": flight.get("cross_grid_flown"),
        "rolling_shutter": survey.get("rolling_shutter"),
        "frames": survey["frames"],
        "sun": survey.get("sun"),
        "gnss_mean_error_enu_m": survey["gnss"].get("mean_error_enu_m"),
    }


def _reconstruct(
    manifest: Manifest,
    survey: dict[str, Any],
    run: Path,
    method: str,
    gnss: str,
    readout_s: float = 0.0,
    from_stage: str | None = None,
) -> dict[str, Any]:
    """One reconstruction of the survey and its figures against the truth. A flight the
    pipeline turns down (InputError) is a failure with its message; so is any other
    error, with its type, so that one flight does not end the whole benchmark. With
    `from_stage`, an earlier run's stages before it are reused where that run got past
    the reconstruct stage; its wall-time figures are then left out."""
    reused = from_stage is not None and (run / "reconstruct.json").is_file()
    if not reused:
        shutil.rmtree(run, ignore_errors=True)
    inputs = ReconstructionInputs(
        video=str(manifest.resolve(survey["video"])),
        log=str(manifest.resolve(survey["flight_log_csv"])),
    )
    start = time.perf_counter()
    try:
        options = reconstruction_options(method, gnss, readout_s)
        result = reconstruct_survey(inputs, run, options, from_stage=from_stage if reused else None)
    except InputError as exc:
        return _failed("input_error", str(exc), start)
    except Exception as exc:  # reported per flight: see the docstring
        detail = traceback.format_exception_only(exc)[-1].strip()
        return _failed("error", detail, start)
    wall = time.perf_counter() - start
    out: dict[str, Any] = {"success": True, "wall_seconds": round(wall, 2)}
    results = dict(result.results)
    for stage in STAGES:  # the reused stages' results
        if stage not in results:
            results[stage] = json.loads((run / f"{stage}.json").read_text())
    # sfm too: its speed is only worth comparing where its result is as good.
    out.update(_against_truth(run, results, manifest, survey, wall))
    if reused:
        # Part of the pipeline ran: no whole-pipeline time to report.
        out.update({"reused_before": from_stage, "wall_seconds": None})
        out["real_time_factor_pipeline"] = None
    return out


def _against_truth(
    run: Path,
    results: dict[str, Any],
    manifest: Manifest,
    survey: dict[str, Any],
    wall: float,
) -> dict[str, Any]:
    """A reconstruction's figures against the simulator's truth. A DSM that cannot
    be co-registered onto its truth (the iterations run out of stable cells: the DSM is
    far off) makes the flight a failure, with its other figures kept."""
    truth_dsm = manifest.resolve(manifest.steps[0]["truth"]["dsm"])
    truth = read_truth_trajectory(manifest.resolve(survey["trajectory"]))
    report = json.loads((run / "report.json").read_text())
    dsm = results["dsm"]["dsm"]
    pixel = float(dsm["resolution_m"])
    measured = dsm_errors(run, truth_dsm)["measured"]
    as_georef, bias = measured.get("nmad"), measured.get("median")
    out: dict[str, Any] = {
        "dsm_pixel_m": pixel,
        "dsm_nmad_as_georeferenced_m": as_georef,
        "dsm_nmad_as_georeferenced_px": None if as_georef is None else round(as_georef / pixel, 2),
        # The NMAD leaves out an offset common to the whole DSM; this is it (|median|).
        "dsm_bias_as_georeferenced_px": None if bias is None else round(abs(bias) / pixel, 2),
        "completeness": dsm["completeness"],
        "trajectory": trajectory_errors(run, truth),
        "georeference": _georef_residuals(results["georeference"]),
        "stage_seconds": report["timings_s"],
        "real_time_factor_reconstruct": report["real_time_factor"],
        "real_time_factor_pipeline": round(results["reconstruct"]["video_seconds"] / wall, 3),
        "quality_passed": report["quality"]["passed"],
        # The DSM's own noise check (quality.py `height_agreement`): None where not made.
        "height_agreement_passed": next(
            (c["passed"] for c in report["quality"]["checks"] if c["name"] == "height_agreement"),
            None,
        ),
        "warnings": report["warnings"],
    }
    try:
        coreg = coregistered_error(run, truth_dsm, pixel)
    except InputError as exc:
        out["success"] = False
        out["failure"] = {"kind": "coregistration", "message": str(exc)[:500]}
        return out
    out["dsm_nmad_coregistered_m"] = coreg["nmad_after_m"]
    out["dsm_nmad_coregistered_px"] = coreg["nmad_px"]
    out["coregistration_shift_enu_m"] = coreg["shift_enu_m"]
    return out


def _failed(kind: str, message: str, start: float) -> dict[str, Any]:
    return {
        "success": False,
        "failure": {"kind": kind, "message": message[:500]},
        "wall_seconds": round(time.perf_counter() - start, 2),
    }


def _georef_residuals(geo: dict[str, Any]) -> dict[str, Any]:
    """Per kept segment: residuals after the adjustment and whether they are within the
    log's stated accuracy; the worst horizontal RMS over them."""
    segments = []
    for seg in geo.get("segments", []):
        after = seg.get("residuals_after_m") or seg.get("fit", {}).get("residuals_m") or {}
        segments.append(
            {
                "segment": seg.get("segment"),
                "frames": seg.get("frames"),
                "rms_h_m": round(math.hypot(after["rms_east"], after["rms_north"]), 4)
                if "rms_east" in after
                else None,
                "rms_up_m": after.get("rms_up"),
                "within_stated_accuracy": seg.get("within_stated_accuracy"),
            }
        )
    rms_h = [s["rms_h_m"] for s in segments if s["rms_h_m"] is not None]
    flags = [s["within_stated_accuracy"] for s in segments]
    return {
        "segments": segments,
        "worst_rms_h_m": max(rms_h) if rms_h else None,
        "all_within_stated_accuracy": all(flags) if flags and None not in flags else None,
        "time_offset_s": geo.get("time_offset_s"),
    }


def run_flights(
    seeds: list[int],
    work_root: Path,
    settings: FlightSettings,
    scenarios: tuple[str, ...],
    sfm_every: int,
    on_flight: Callable[[list[dict[str, Any]]], None] | None = None,
    fixed: FixedConditions | None = None,
) -> list[dict[str, Any]]:
    """Every flight, one after the other (each uses the machine's cores itself);
    `on_flight(records)` after each, so a long run can save what it has."""
    records: list[dict[str, Any]] = []
    for i, seed in enumerate(seeds):
        cond = draw_conditions(seed, scenarios, settings.video_seconds, fixed)
        with_sfm = sfm_every > 0 and i % sfm_every == 0
        records.append(run_flight(cond, work_root / f"seed{seed:04d}", settings, with_sfm))
        if on_flight is not None:
            on_flight(records)
    return records
