"""`slidewatch bench reconstruction`: slam against sfm on simulated surveys.

    slidewatch bench reconstruction --json benchmarks/results/reconstruction.json

A subcommand of the `bench` group (worker/commands/bench.py). It runs
benchmarks/reconstruction.py, which documents every figure; the work directory keeps
the simulated surveys for re-runs.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import click

_SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "reconstruction.py"


@click.command("reconstruction")
@click.option("--json", "json_path", type=click.Path(path_type=Path), required=True)
@click.option(
    "--work-dir",
    type=click.Path(path_type=Path),
    default=Path("data/bench-reconstruction"),
    show_default=True,
)
@click.option(
    "--scenario",
    "scenarios",
    multiple=True,
    type=click.Choice(["paper-mounds", "hillslope"]),
    help="Default: both.",
)
@click.option("--video-seconds", type=float, default=None, help="Default: the whole plan.")
@click.option("--width", type=int, default=1280, show_default=True)
@click.option("--height", type=int, default=720, show_default=True)
@click.option("--fps", type=float, default=30.0, show_default=True)
@click.option("--gnss-trials", type=int, default=3, show_default=True)
@click.option(
    "--repeat-flights",
    type=int,
    default=3,
    show_default=True,
    help="Flights of the repeated-flight (paper Table 1) experiment; 0 skips it.",
)
def reconstruction(
    json_path: Path,
    work_dir: Path,
    scenarios: tuple[str, ...],
    video_seconds: float | None,
    width: int,
    height: int,
    fps: float,
    gnss_trials: int,
    repeat_flights: int,
) -> None:
    """Wall time slam vs sfm, real-time factor, DSM, trajectory and georeferencing error."""
    spec = importlib.util.spec_from_file_location("bench_reconstruction", _SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    argv = ["--json", str(json_path), "--work-dir", str(work_dir)]
    argv += ["--width", str(width), "--height", str(height), "--fps", str(fps)]
    argv += ["--gnss-trials", str(gnss_trials), "--repeat-flights", str(repeat_flights)]
    if video_seconds is not None:
        argv += ["--video-seconds", str(video_seconds)]
    for name in scenarios:
        argv += ["--scenario", name]
    module.main(argv)
