"""`slidewatch bench reconstruction`: slam against sfm on simulated surveys.

    slidewatch bench reconstruction --json benchmarks/results/reconstruction.json
    slidewatch bench reconstruction --flights 20 --json benchmarks/results/flights.json

A subcommand of the `bench` group (worker/commands/bench.py). Without `--flights` it runs
benchmarks/reconstruction.py (one survey per scenario, in depth); with `--flights N` it
runs benchmarks/flights_run.py (N flights, each drawing its conditions from its seed,
summarised per scenario x GNSS mode). Those modules document every figure; the work
directory keeps the simulated surveys for re-runs.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import click
from click.core import ParameterSource

_BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def load_benchmark(name: str) -> ModuleType:
    """benchmarks/<name>.py as a module. The benchmarks are scripts, not a package: they
    import their shared modules (dsm_truth, flights ...) by name from their own folder,
    as Python does for a script, so that folder goes on the path first."""
    if str(_BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(_BENCHMARKS))
    spec = importlib.util.spec_from_file_location(f"bench_{name}", _BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


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
@click.option(
    "--video-seconds",
    type=float,
    default=None,
    help="Default: the whole plan; with --flights, each flight draws 20-30 s.",
)
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
@click.option(
    "--flights",
    type=int,
    default=0,
    help="Run N simulated flights instead, each with conditions drawn from its seed "
    "(benchmarks/flights.py); the video is then 640x360 unless --width/--height say.",
)
@click.option("--first-seed", type=int, default=1, show_default=True, help="With --flights.")
@click.option(
    "--sfm-every",
    type=int,
    default=5,
    show_default=True,
    help="With --flights: every K-th flight is also reconstructed with sfm (0: none).",
)
@click.option(
    "--gnss",
    type=click.Choice(["standalone", "rtk"]),
    default=None,
    help="With --flights: every flight's GNSS mode (default: alternating).",
)
@click.option(
    "--plan",
    type=click.Choice(["lawnmower", "paper-3d"]),
    default=None,
    help="With --flights: every flight's plan (default: drawn; paper-3d is the mounds').",
)
@click.option(
    "--altitude",
    type=float,
    default=None,
    help="With --flights: every flight's height in metres (default: drawn).",
)
@click.option(
    "--plain",
    is_flag=True,
    help="With --flights: no harder condition (cross, low sun, texture-poor, rolling "
    "shutter) and the simulator's own render noise.",
)
@click.option(
    "--rolling-shutter",
    "rolling_shutter_ms",
    type=click.FloatRange(0.0, 33.0),
    default=None,
    help="With --flights: every flight's rolling-shutter readout in ms (0: a global "
    "shutter; default: drawn with the harder conditions).",
)
@click.option(
    "--no-readout",
    is_flag=True,
    help="With --flights: do not give a rolling-shutter flight's readout to the pipeline "
    "(a user who does not know it); by default it is given, as the camera's.",
)
@click.option(
    "--from-stage",
    type=click.Choice(["georeference", "dsm", "orthophoto"]),
    default=None,
    help="With --flights: reuse each flight's reconstruction from an earlier run in the "
    "same --work-dir and run the stages from this one on (to measure a change to them on "
    "the same reconstructions); wall times are then not reported.",
)
@click.pass_context
def reconstruction(
    ctx: click.Context,
    json_path: Path,
    work_dir: Path,
    scenarios: tuple[str, ...],
    video_seconds: float | None,
    width: int,
    height: int,
    fps: float,
    gnss_trials: int,
    repeat_flights: int,
    flights: int,
    first_seed: int,
    sfm_every: int,
    gnss: str | None,
    plan: str | None,
    altitude: float | None,
    plain: bool,
    rolling_shutter_ms: float | None,
    no_readout: bool,
    from_stage: str | None,
) -> None:
    """Wall time slam vs sfm, real-time factor, DSM, trajectory and georeferencing error."""
    if flights > 0:
        # The many-flight run's own default size: short, small videos (issue 18).
        if ctx.get_parameter_source("width") is ParameterSource.DEFAULT:
            width = 640
        if ctx.get_parameter_source("height") is ParameterSource.DEFAULT:
            height = 360
        seeds = list(range(first_seed, first_seed + flights))
        flights_run = load_benchmark("flights_run")
        fixed = flights_run.FixedConditions(
            gnss=gnss,
            plan=plan,
            altitude_m=altitude,
            plain=plain,
            rolling_shutter_s=None if rolling_shutter_ms is None else rolling_shutter_ms / 1000.0,
        )
        report = flights_run.run(
            json_path,
            work_dir,
            seeds,
            scenarios,
            video_seconds,
            (width, height, fps),
            sfm_every,
            fixed,
            readout_given=not no_readout,
            from_stage=from_stage,
        )
        click.echo(report["table"])
        return
    module = load_benchmark("reconstruction")
    argv = ["--json", str(json_path), "--work-dir", str(work_dir)]
    argv += ["--width", str(width), "--height", str(height), "--fps", str(fps)]
    argv += ["--gnss-trials", str(gnss_trials), "--repeat-flights", str(repeat_flights)]
    if video_seconds is not None:
        argv += ["--video-seconds", str(video_seconds)]
    for name in scenarios:
        argv += ["--scenario", name]
    module.main(argv)
