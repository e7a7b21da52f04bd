"""`slidewatch bench orthophoto`: the orthophoto stage's accuracy and cost over seeds.

    slidewatch bench orthophoto --scenario hillslope --seeds 3 --json OUT.json

A subcommand of the `bench` group (worker/commands/bench.py). Per seed it simulates a
survey (`--survey video` with its log, or `images`), reconstructs it through every stage
(the library's `reconstruct_survey`, as the CLI and the worker run it) and compares the
orthophoto with the simulator's truth orthoimage (worker/simulator/orthophoto_truth.py):
feature positions after the survey's georeferencing offset and after the georeference's
rotation and scale. Cost: the orthophoto stage's seconds, and the whole survey's seconds
against the video's length (real time: a survey no slower than it was flown). Surveys
and reconstructions are kept under `--work-dir` and reused unless `--fresh`.

The figures are median, p90 and worst over the seeds. The orthophoto method's parameters
were set on the paper-mounds video of seed 3 (the test's survey); other scenarios, seeds
and photo surveys were not used to tune it.
"""

from __future__ import annotations

import csv
import json
import shutil
import time
from pathlib import Path
from typing import Any

import click
import numpy as np

ORTHOPHOTO_FIGURES = ("width", "height", "resolution_m", "scale", "views", "keyframes", "coverage")


def _bias(recon: Path, flight: Path) -> tuple[float, float]:
    """The trajectory's mean horizontal offset from the flown one (the survey's GNSS bias):
    a video's frames against trajectory.csv, a photo set's cameras against images.csv."""
    from worker.pipeline.trajectory import read_trajectory_csv

    truth_csv = flight / "trajectory.csv"
    if not truth_csv.is_file():
        truth_csv = flight / "images.csv"
    if not truth_csv.is_file() or not (recon / "trajectory.csv").is_file():
        return 0.0, 0.0
    traj = read_trajectory_csv(recon / "trajectory.csv")
    with open(truth_csv, encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["t_s"]) for r in rows])
    east = np.interp(traj.t, t, [float(r["e"]) for r in rows])
    north = np.interp(traj.t, t, [float(r["n"]) for r in rows])
    return float(np.mean(traj.positions[:, 0] - east)), float(np.mean(traj.positions[:, 1] - north))


def _one(seed: int, options: dict[str, Any], work: Path, fresh: bool) -> dict[str, Any]:
    from worker.pipeline.reconstruction import (
        ReconstructionInputs,
        ReconstructionOptions,
        reconstruct_survey,
    )
    from worker.simulator.orthophoto_truth import orthophoto_errors
    from worker.simulator.simulate import SimulationOptions, simulate_scenario

    sim = work / f"seed{seed}" / "sim"
    recon = work / f"seed{seed}" / "recon"
    if fresh:
        shutil.rmtree(work / f"seed{seed}", ignore_errors=True)
    flight, truth = sim / "step1" / "flight1", sim / "step1" / "truth"
    if not (truth / "ortho.tif").is_file():
        simulate_scenario(
            options["scenario"],
            sim,
            SimulationOptions(
                steps=1,
                seed=seed,
                survey=options["survey"],
                video_seconds=options["video_seconds"],
                width=options["width"],
                height=options["height"],
                fps=options["fps"],
                gnss=options["gnss"],
                registration=False,
                workers=1,
            ),
        )
    if options["survey"] == "images":
        inputs = ReconstructionInputs(images=str(flight / "images"))
    else:
        inputs = ReconstructionInputs(
            video=str(flight / "DJI_0001.MP4"), log=str(flight / "flight-airdata.csv")
        )
    error = None
    started = time.perf_counter()
    if fresh or not (recon / "orthophoto.json").is_file():
        try:
            reconstruct_survey(inputs, recon, ReconstructionOptions())
        except Exception as exc:  # a failed flight is a figure of the benchmark too
            error = f"{type(exc).__name__}: {exc}"
    wall = time.perf_counter() - started
    row: dict[str, Any] = {"seed": seed, "error": error, "wall_seconds": round(wall, 1)}
    if error:
        return row
    report = json.loads((recon / "report.json").read_text())
    stage = report["stages"]["orthophoto"]
    made = stage.get("orthophoto")
    video_s = report["stages"]["reconstruct"].get("video_seconds") or 0.0
    row.update(
        {
            "stage_seconds": report["timings_s"],
            "survey_seconds": report["total_s"],
            "video_seconds": round(video_s, 2),
            "orthophoto_seconds": stage["seconds"],
            "warnings": stage["warnings"],
        }
    )
    if made is None:
        row["error"] = "no orthophoto: " + "; ".join(stage["warnings"])
        return row
    errors = orthophoto_errors(recon / "orthophoto.tif", truth / "ortho.tif", _bias(recon, flight))
    row.update(
        {
            "orthophoto": {k: made[k] for k in ORTHOPHOTO_FIGURES},
            "errors": errors.to_dict(),
        }
    )
    return row


def _line(row: dict[str, Any]) -> str:
    if row.get("error"):
        return row["error"]
    e = row["errors"]
    return (
        f"residual {e['residual_median_px']:.2f} px (p90 {e['residual_p90_px']:.2f}), "
        f"local p90 {e['local_p90_px']:.2f} px at {e['pixel_m']:.3f} m; orthophoto "
        f"{row['orthophoto_seconds']:.1f} s, survey {row['survey_seconds']:.1f} s for "
        f"{row['video_seconds']:.1f} s of video"
    )


def _stats(values: list[float]) -> dict[str, float | None]:
    finite = [v for v in values if v is not None and np.isfinite(v)]
    if not finite:
        return {"median": None, "p90": None, "worst": None}
    return {
        "median": round(float(np.median(finite)), 3),
        "p90": round(float(np.percentile(finite, 90)), 3),
        "worst": round(float(max(finite)), 3),
    }


@click.command("orthophoto")
@click.option("--scenario", type=click.Choice(["paper-mounds", "hillslope"]), default="hillslope")
@click.option("--survey", type=click.Choice(["video", "images"]), default="video")
@click.option("--seeds", type=click.IntRange(1, 50), default=3, show_default=True)
@click.option("--first-seed", type=int, default=1, show_default=True)
@click.option("--video-seconds", type=float, default=30.0, show_default=True)
@click.option("--width", type=int, default=1280, show_default=True)
@click.option("--height", type=int, default=720, show_default=True)
@click.option("--fps", type=float, default=15.0, show_default=True)
@click.option("--gnss", type=click.Choice(["standalone", "rtk"]), default="rtk", show_default=True)
@click.option("--work-dir", type=click.Path(path_type=Path), default=Path("bench-orthophoto"))
@click.option("--fresh", is_flag=True, help="Simulate and reconstruct again.")
@click.option("--json", "json_out", type=click.Path(path_type=Path), required=True)
def orthophoto(
    scenario: str,
    survey: str,
    seeds: int,
    first_seed: int,
    video_seconds: float,
    width: int,
    height: int,
    fps: float,
    gnss: str,
    work_dir: Path,
    fresh: bool,
    json_out: Path,
) -> None:
    """The orthophoto's accuracy against the simulator's truth and its cost, per seed."""
    options = {
        "scenario": scenario,
        "survey": survey,
        "video_seconds": video_seconds,
        "width": width,
        "height": height,
        "fps": fps,
        "gnss": gnss,
    }
    rows = []
    for seed in range(first_seed, first_seed + seeds):
        row = _one(seed, options, work_dir, fresh)
        rows.append(row)
        click.echo(f"seed {seed}: {_line(row)}")
    ok = [r for r in rows if not r.get("error")]
    summary = {
        "flights": len(rows),
        "failed": [{"seed": r["seed"], "error": r["error"]} for r in rows if r.get("error")],
        "residual_median_px": _stats([r["errors"]["residual_median_px"] for r in ok]),
        "residual_p90_px": _stats([r["errors"]["residual_p90_px"] for r in ok]),
        "local_p90_px": _stats([r["errors"]["local_p90_px"] for r in ok]),
        "correlation_worst": min((r["errors"]["correlation"] for r in ok), default=None),
        "coverage": _stats([r["orthophoto"]["coverage"] for r in ok]),
        "orthophoto_seconds": _stats([r["orthophoto_seconds"] for r in ok]),
        # Real time: the survey's processing over the video's length (<= 1: no slower).
        "survey_seconds_per_video_second": _stats(
            [r["survey_seconds"] / r["video_seconds"] for r in ok if r["video_seconds"]]
        ),
        "orthophoto_seconds_per_video_second": _stats(
            [r["orthophoto_seconds"] / r["video_seconds"] for r in ok if r["video_seconds"]]
        ),
        "target_residual_px": 2.0,
    }
    result = {"options": options, "summary": summary, "flights": rows}
    json_out.parent.mkdir(parents=True, exist_ok=True)
    json_out.write_text(json.dumps(result, indent=2))
    click.echo(json.dumps(summary, indent=2))
