"""Benchmark of the reconstruction: slam against sfm on simulated surveys, in one run.

Usage:
    .venv/bin/python benchmarks/reconstruction.py --json OUT.json [--scenario paper-mounds]
        [--video-seconds S] [--width 1280 --height 720] [--fps 30] [--work-dir DIR]
(also `slidewatch bench reconstruction`, see worker/commands/bench_reconstruction.py)

For each scenario (paper-mounds: the paper's field flown at 7 m; hillslope: a real-scale
slope flown at 90 m) the simulator renders one survey video with its DJI SRT and AirData
CSV (stand-alone GPS) and the truth. Then, on this machine, in one run:

- wall time of `slam` and of `sfm` over the whole pipeline (ingest .. dsm) from the same
  video and log, and their ratio; `slam` works on 640x360 frames, `sfm` on stills at
  3 fps at the video's full size (the paper gave OpenDroneMap 2560 px frames at 3 fps);
  both in a process that has imported its libraries, as a worker has;
- real-time factor: video seconds per second of the slam reconstruct stage, and per
  second of the whole slam pipeline;
- DSM error against the truth DSM: NMAD, 95th percentile of |error - median|, median,
  and completeness (cells with points / cells in the footprint, before inpainting),
  once "as georeferenced" (stand-alone GPS: dominated by the flight's GNSS bias) and
  once "reconstruction only" (the georeferencing error removed by the similarity that
  maps the estimated camera centres onto the true ones, as the paper georeferenced its
  efficiency experiment manually), and once after co-registering the DSM onto the truth
  (shift and tilt, as the comparison co-registers two surveys), in DSM pixels too;
- trajectory error: RMSE of camera centres after that similarity (shape), and after
  georeferencing (absolute);
- georeferencing error east/north/up (the paper's Table 1 analogue): the slam
  reconstruction is georeferenced with logs of `--gnss-trials` GNSS realisations (the
  simulator's error models, from the true trajectory) with stand-alone GPS and with RTK,
  by `paper4` and by the default `similarity`; the error at the scenario's checkpoints
  (paper-mounds: the three targets; hillslope: a 5 x 5 grid over the survey) is
  predicted from the camera-centre similarity (estimated vs. true). Reported as mean
  |error| per axis (like Table 1) and the same after removing each flight's mean GNSS
  error (the part no method without control points can see).
- repeated flights (the paper's own Table 1 experiment): the same plan flown
  `--repeat-flights` times with nothing changed on the ground (each flight its own
  stand-alone GNSS bias, drift, sun and exposure), each reconstructed by `slam` and
  georeferenced from its own log; the checkpoints' positions in each georeferenced model
  (from the camera-centre similarity) give the paper's figure, the mean pairwise location
  difference per axis, once as georeferenced and once after co-registering each DSM
  onto the first flight's (what change detection compares).

Targets from the issue: slam >= 10x faster than sfm; real-time factor >= 1; DSM NMAD
<= 2 x DSM pixel; stand-alone georeferencing error below 0.77 / 1.06 / 1.22 m (E/N/U).
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
from dsm_truth import (
    coregistered_error,
    dsm_errors,
    read_truth_trajectory,
    trajectory_errors,
    truth_at,
)

from worker.pipeline.georef import umeyama
from worker.pipeline.reconstruction import (
    ReconstructionInputs,
    ReconstructionOptions,
    georeference,
    reconstruct_survey,
)
from worker.pipeline.repeatability import coregister_checkpoints, mean_pairwise_difference
from worker.pipeline.slam.result import SparseMap
from worker.simulator.gnss import (
    GnssErrorModel,
    ImuErrorModel,
    simulate_attitude_errors,
    simulate_gnss,
)
from worker.simulator.manifest import Manifest
from worker.simulator.simulate import SimulationOptions, simulate_scenario

PAPER_TABLE1_M = {"east": 0.77, "north": 1.06, "up": 1.22}
SCENARIOS = ("paper-mounds", "hillslope")


# -- truth -------------------------------------------------------------------------------
def checkpoints(manifest: Manifest, truth: dict[str, np.ndarray]) -> np.ndarray:
    cps = manifest.data.get("scene", {}).get("checkpoints") or []
    if cps:
        return np.array([[c["e"], c["n"], c["u"]] for c in cps])
    e, n = truth["e"], truth["n"]
    ge, gn = np.meshgrid(np.linspace(e.min(), e.max(), 5), np.linspace(n.min(), n.max(), 5))
    ground = np.median(truth["u"]) - 90.0
    return np.column_stack([ge.ravel(), gn.ravel(), np.full(ge.size, ground)])


# -- synthetic logs for the georeferencing table ------------------------------------------
def write_log(
    path: Path, truth: dict[str, np.ndarray], crs: str, mode: str, seed: int
) -> np.ndarray:
    """A generic CSV (video clock) of the true trajectory plus simulated GNSS and
    attitude errors; returns the mean ENU error of the positions."""
    from pyproj import Transformer

    rng = np.random.default_rng([seed, 7])
    t = np.arange(truth["t_s"][0], truth["t_s"][-1], 0.1)
    gnss = simulate_gnss(GnssErrorModel.named(mode), t[0], t[-1], rng)
    att = simulate_attitude_errors(ImuErrorModel(), t[0], t[-1], rng)
    err = gnss.error_at(t)
    enu = truth_at(truth, t, ("e", "n", "u")) + err
    _, gim = att.at(t)
    cam = truth_at(truth, t, ("camera_yaw_deg", "camera_pitch_deg", "camera_roll_deg"))
    lon, lat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(
        enu[:, 0], enu[:, 1]
    )
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("time,lat,lon,alt,gimbal_yaw,gimbal_pitch,gimbal_roll\n")
        for i in range(t.size):
            g = cam[i] + gim[i]
            fh.write(
                f"{t[i]:.3f},{lat[i]:.9f},{lon[i]:.9f},{enu[i, 2]:.4f},"
                f"{g[0]:.3f},{g[1]:.3f},{g[2]:.3f}\n"
            )
    return err.mean(axis=0)


def georef_table(
    slam_work: Path,
    work: Path,
    truth: dict[str, np.ndarray],
    crs: str,
    cps: np.ndarray,
    trials: int,
) -> dict[str, Any]:
    """Checkpoint errors per GNSS mode and georeferencing method (see the module doc)."""
    out: dict[str, Any] = {}
    for mode in ("standalone", "rtk"):
        for method in ("paper4", "similarity"):
            errors, beyond = [], []
            failures = []
            for trial in range(trials):
                run = work / f"georef-{mode}-{method}-{trial}"
                if run.exists():
                    shutil.rmtree(run)
                run.mkdir(parents=True)
                for name in ("ingest.json", "frames.json", "reconstruct.json"):
                    shutil.copy(slam_work / name, run / name)
                shutil.copytree(slam_work / "reconstruct", run / "reconstruct")
                log = run / "log.csv"
                bias = write_log(log, truth, crs, mode, trial)
                ingest = json.loads((run / "ingest.json").read_text())
                ingest["inputs"]["log"] = str(log)
                (run / "ingest.json").write_text(json.dumps(ingest))
                options = ReconstructionOptions(time_offset_s=0.0)
                options.georef.georef.method = method
                frames = json.loads((run / "frames.json").read_text())
                frames["time_offset"] = {
                    "offset_s": 0.0,
                    "prior_s": 0.0,
                    "prior_source": "user",
                    "method": "user",
                    "score": None,
                    "observable": True,
                    "warnings": [],
                }
                (run / "frames.json").write_text(json.dumps(frames))
                try:
                    georeference(run, options)
                except Exception as exc:  # paper4 fails on planar tracks: report it
                    failures.append(str(exc)[:200])
                    continue
                sparse = SparseMap.load(run / "georeference" / "map.npz")
                traj = sparse.trajectory()
                true = truth_at(truth, traj.t, ("e", "n", "u"))
                true_to_est = umeyama(true, traj.positions)
                e = true_to_est.apply(cps) - cps
                errors.append(np.abs(e).mean(axis=0))
                beyond.append(np.abs(e - bias).mean(axis=0))
            key = f"{mode}/{method}"
            if errors:
                m = np.mean(errors, axis=0)
                b = np.mean(beyond, axis=0)
                out[key] = {
                    "trials": len(errors),
                    "east_m": round(float(m[0]), 4),
                    "north_m": round(float(m[1]), 4),
                    "up_m": round(float(m[2]), 4),
                    "beyond_gnss_bias_m": [round(float(v), 4) for v in b],
                    "failures": failures,
                }
            else:
                out[key] = {"trials": 0, "failures": failures}
    return out


# -- one scenario ------------------------------------------------------------------------
def run_scenario(name: str, work: Path, args: argparse.Namespace) -> dict[str, Any]:
    sim_dir = work / "sim"
    t0 = time.perf_counter()
    if not (sim_dir / "manifest.json").is_file():
        simulate_scenario(name, sim_dir, _simulation_options(args))
    sim_seconds = time.perf_counter() - t0
    manifest = Manifest(root=sim_dir, data=json.loads((sim_dir / "manifest.json").read_text()))
    survey = manifest.steps[0]["surveys"][0]
    video = manifest.resolve(survey["video"])
    log = manifest.resolve(survey["flight_log_csv"])
    truth_dsm = manifest.resolve(manifest.steps[0]["truth"]["dsm"])
    truth = read_truth_trajectory(manifest.resolve(survey["trajectory"]))
    crs = manifest.data["crs"]
    inputs = ReconstructionInputs(video=str(video), log=str(log))
    result: dict[str, Any] = {
        "scenario": name,
        "simulation_seconds": round(sim_seconds, 1),
        "video": {k: survey[k] for k in ("frames", "fps", "width", "height")},
        "flight": {
            k: survey["flight"].get(k) for k in ("speed_m_s", "path_length_m", "duration_s")
        },
    }
    methods: dict[str, Any] = {}
    for method in ("slam", "sfm"):
        run = work / method
        if run.exists():
            shutil.rmtree(run)
        start = time.perf_counter()
        rec = reconstruct_survey(inputs, run, ReconstructionOptions(method=method))
        wall = time.perf_counter() - start
        traj = trajectory_errors(run, truth)
        sparse = SparseMap.load(run / "georeference" / "map.npz")
        est = sparse.trajectory()
        to_truth = umeyama(est.positions, truth_at(truth, est.t, ("e", "n", "u")))
        dsm_json = rec.results["dsm"]["dsm"]
        methods[method] = {
            "wall_seconds": round(wall, 2),
            "stage_seconds": {s: r.get("seconds") for s, r in rec.results.items()},
            "dsm_resolution_m": dsm_json["resolution_m"],
            "completeness_before_inpainting": dsm_json["completeness"],
            "dsm_error_as_georeferenced_m": dsm_errors(run, truth_dsm),
            "dsm_error_reconstruction_only_m": dsm_errors(run, truth_dsm, to_truth),
            "dsm_error_after_coregistration": coregistered_error(
                run, truth_dsm, dsm_json["resolution_m"]
            ),
            "trajectory": traj,
            "georef_residuals_m": rec.results["georeference"]["segments"][0]["residuals_after_m"],
            "time_offset_s": rec.results["georeference"]["time_offset"]["offset_s"],
            "reconstruct": {
                k: rec.results["reconstruct"].get(k)
                for k in ("keyframes", "segments", "sparse_points", "dense_points", "sfm")
            },
        }
        if method == "slam":
            video_s = rec.results["reconstruct"]["video_seconds"]
            methods[method]["real_time_factor_reconstruct"] = rec.results["reconstruct"][
                "real_time_factor"
            ]
            methods[method]["real_time_factor_pipeline"] = round(video_s / wall, 3)
    result["methods"] = methods
    result["sfm_over_slam_wall_time"] = round(
        methods["sfm"]["wall_seconds"] / methods["slam"]["wall_seconds"], 2
    )
    cps = checkpoints(manifest, truth)
    result["georeferencing_checkpoints"] = len(cps)
    result["georeferencing"] = georef_table(work / "slam", work, truth, crs, cps, args.gnss_trials)
    if args.repeat_flights >= 2:
        result["repeated_flights"] = repeated_flights(name, work, args)
    return result


# -- repeated flights: the paper's Table 1 -------------------------------------------------
def _simulation_options(args: argparse.Namespace, **changes: Any) -> SimulationOptions:
    return SimulationOptions(
        seed=args.seed,
        steps=1,
        survey="video",
        video_seconds=args.video_seconds,
        width=args.width,
        height=args.height,
        fps=args.fps,
        registration=False,
        write_ortho=False,
        workers=args.render_workers,
        **changes,
    )


def _rounded(values: np.ndarray) -> list[float]:
    return [round(float(v), 4) for v in values]


def repeated_flights(name: str, work: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Mean pairwise checkpoint difference of repeated flights (see the module doc)."""
    sim_dir = work / "repeat-sim"
    if not (sim_dir / "manifest.json").is_file():
        options = _simulation_options(args, flights_per_step=args.repeat_flights, slides=False)
        simulate_scenario(name, sim_dir, options)
    manifest = Manifest(root=sim_dir, data=json.loads((sim_dir / "manifest.json").read_text()))
    surveys = manifest.steps[0]["surveys"]
    true_cps = checkpoints(
        manifest, read_truth_trajectory(manifest.resolve(surveys[0]["trajectory"]))
    )
    positions, dsms, flights = [], [], []
    for j, survey in enumerate(surveys):
        run = work / f"repeat-flight{j + 1}"
        if run.exists():
            shutil.rmtree(run)
        inputs = ReconstructionInputs(
            video=str(manifest.resolve(survey["video"])),
            log=str(manifest.resolve(survey["flight_log_csv"])),
        )
        start = time.perf_counter()
        reconstruct_survey(inputs, run, ReconstructionOptions())
        wall = time.perf_counter() - start
        truth = read_truth_trajectory(manifest.resolve(survey["trajectory"]))
        traj = SparseMap.load(run / "georeference" / "map.npz").trajectory()
        true_to_est = umeyama(truth_at(truth, traj.t, ("e", "n", "u")), traj.positions)
        positions.append(true_to_est.apply(true_cps))
        dsms.append(run / "dsm.tif")
        flights.append(
            {
                "wall_seconds": round(wall, 2),
                "gnss_mean_error_enu_m": survey["gnss"]["mean_error_enu_m"],
                "checkpoint_error_enu_m": _rounded(np.abs(positions[-1] - true_cps).mean(axis=0)),
            }
        )
    coregistered = [positions[0]]
    for j in range(1, len(surveys)):
        moved, correction = coregister_checkpoints(dsms[0], dsms[j], positions[j])
        coregistered.append(moved)
        flights[j]["coregistration_onto_flight1_m"] = {
            k: round(v, 4) if isinstance(v, float) else v
            for k, v in correction.to_dict().items()
            if k.startswith(("shift_", "tilt_east", "tilt_north", "nmad_"))
        }
    as_georeferenced = mean_pairwise_difference(positions)
    after_coregistration = mean_pairwise_difference(coregistered)
    return {
        "flights": flights,
        "checkpoints": len(true_cps),
        "mean_pairwise_difference_as_georeferenced_m": dict(
            zip(("east", "north", "up"), _rounded(as_georeferenced), strict=True)
        ),
        "mean_pairwise_difference_after_coregistration_m": dict(
            zip(("east", "north", "up"), _rounded(after_coregistration), strict=True)
        ),
    }


def warm_imports() -> None:
    """A worker process imports its heavy libraries once, not once per survey: import
    them before any timing so that neither method pays for them (open3d alone takes
    ~0.7 s, and only the method timed first would pay)."""
    import open3d  # noqa: F401
    import pycolmap  # noqa: F401


def run_benchmark(args: argparse.Namespace) -> dict[str, Any]:
    warm_imports()
    work_root = Path(args.work_dir)
    report: dict[str, Any] = {
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor(),
            "python": platform.python_version(),
        },
        "settings": vars(args) | {"json": str(args.json)},
        "paper": {"sfm_over_dso": 5.53, "table1_m": PAPER_TABLE1_M},
        "scenarios": {},
    }
    start = time.perf_counter()
    for name in args.scenario or SCENARIOS:
        report["scenarios"][name] = run_scenario(name, work_root / name, args)
        print(json.dumps(summarize(report["scenarios"][name]), indent=1), flush=True)
    report["seconds"] = round(time.perf_counter() - start, 1)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(report, indent=2))
    return report


def summarize(s: dict[str, Any]) -> dict[str, Any]:
    slam, sfm = s["methods"]["slam"], s["methods"]["sfm"]
    return {
        "scenario": s["scenario"],
        "slam_s": slam["wall_seconds"],
        "sfm_s": sfm["wall_seconds"],
        "sfm_over_slam": s["sfm_over_slam_wall_time"],
        "rtf_reconstruct": slam["real_time_factor_reconstruct"],
        "rtf_pipeline": slam["real_time_factor_pipeline"],
        "slam_dsm_nmad_m": slam["dsm_error_reconstruction_only_m"]["measured"].get("nmad"),
        "sfm_dsm_nmad_m": sfm["dsm_error_reconstruction_only_m"]["measured"].get("nmad"),
        "slam_dsm_nmad_coregistered_px": slam["dsm_error_after_coregistration"]["nmad_px"],
        "sfm_dsm_nmad_coregistered_px": sfm["dsm_error_after_coregistration"]["nmad_px"],
        "dsm_pixel_m": slam["dsm_resolution_m"],
        "slam_completeness": slam["completeness_before_inpainting"],
        "georef": {
            k: [v.get("east_m"), v.get("north_m"), v.get("up_m")]
            for k, v in s["georeferencing"].items()
        },
        "repeated_flights_mean_difference_m": {
            k.removeprefix("mean_pairwise_difference_"): list(v.values())
            for k, v in s.get("repeated_flights", {}).items()
            if k.startswith("mean_pairwise_difference_")
        },
    }


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--json", required=True)
    p.add_argument("--work-dir", default="data/bench-reconstruction")
    p.add_argument("--scenario", action="append", choices=SCENARIOS)
    p.add_argument("--video-seconds", type=float, default=None)
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--gnss-trials", type=int, default=3)
    p.add_argument("--render-workers", type=int, default=1)
    p.add_argument(
        "--repeat-flights", type=int, default=3, help="flights of the Table 1 analogue; 0: skip"
    )
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    run_benchmark(parse_args(argv))


if __name__ == "__main__":
    main()
