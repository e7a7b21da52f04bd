"""`slidewatch simulate`: write a synthetic survey series with known truth."""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

EXIT_INPUT_ERROR = 2


@click.command("simulate")
@click.option(
    "--scenario",
    type=click.Choice(["paper-mounds", "hillslope"]),
    default="paper-mounds",
    show_default=True,
    help="paper-mounds: the paper's one-tenth-scale field; hillslope: real scale.",
)
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(path_type=Path),
    help="Directory to write into (manifest.json describes every file).",
)
@click.option("--seed", default=1, show_default=True, type=int, help="Random seed.")
@click.option(
    "--steps",
    type=click.IntRange(1, 50),
    default=None,
    help="Number of steps (surveys in time) [default: 6 paper-mounds, 2 hillslope].",
)
@click.option(
    "--survey",
    type=click.Choice(["video", "images", "both", "none"]),
    default="video",
    show_default=True,
    help="Video (MP4+SRT), image set (JPEG with EXIF/XMP), both, or truth only.",
)
@click.option(
    "--video-seconds",
    type=click.FloatRange(0.5, None),
    default=None,
    help="Length of each survey; the plan is flown at the speed that fits.",
)
@click.option("--width", type=click.IntRange(64, 3840), default=640, show_default=True)
@click.option("--height", type=click.IntRange(36, 2160), default=360, show_default=True)
@click.option("--fps", type=click.FloatRange(1, 120), default=30.0, show_default=True)
@click.option(
    "--flight",
    type=click.Choice(["lawnmower", "paper-3d"]),
    default=None,
    help="Flight plan [default: lawnmower].",
)
@click.option(
    "--altitude",
    "altitude_m",
    type=click.FloatRange(1, 500),
    default=None,
    help="Flight height in metres [default: 7 paper-mounds, 100 hillslope].",
)
@click.option(
    "--speed",
    "speed_m_s",
    type=click.FloatRange(0.5, 20),
    default=None,
    help="Cruise speed in m/s (ignored with --video-seconds).",
)
@click.option("--flights-per-step", type=click.IntRange(1, 10), default=1, show_default=True)
@click.option(
    "--random-slides",
    type=click.IntRange(0, 20),
    default=0,
    show_default=True,
    help="hillslope: this many random slides instead of the scenario's own (training data).",
)
@click.option(
    "--slides/--no-slides",
    default=True,
    show_default=True,
    help="--no-slides: the steps differ by vegetation growth and small surface changes only.",
)
@click.option(
    "--gnss",
    type=click.Choice(["standalone", "consumer", "field", "rtk", "none"]),
    default="standalone",
    show_default=True,
    help="GNSS error model of the logs: consumer (photo GPS: drifting altitude, outlier "
    "fixes; worker/simulator/gnss.py) or field (held out: stepped bias, barometric walk, "
    "clustered multipath, time-tag slips; worker/simulator/gnss_field.py).",
)
@click.option(
    "--log-time-offset",
    "log_time_offset_s",
    type=float,
    default=0.0,
    show_default=True,
    help="Seconds the CSV flight log lags the video.",
)
@click.option(
    "--csv-units",
    type=click.Choice(["feet", "meters"]),
    default="feet",
    show_default=True,
    help="Units of the AirData CSV.",
)
@click.option(
    "--cross/--no-cross",
    "cross_pattern",
    default=False,
    show_default=True,
    help="Fly the plan again with its lines perpendicular (a cross pattern).",
)
@click.option(
    "--sun-elevation",
    "sun_elevation_deg",
    type=click.FloatRange(0, 90, min_open=True),
    default=None,
    help="The sun's elevation in degrees (low sun: 5-15) [default: drawn, 38-62].",
)
@click.option(
    "--light-gain",
    type=click.FloatRange(0, None, min_open=True),
    default=1.0,
    show_default=True,
    help="Scales the exposure (low light: below 1).",
)
@click.option(
    "--ground-contrast",
    type=click.FloatRange(0, None),
    default=1.0,
    show_default=True,
    help="Scales the ground texture's contrast (texture-poor field: below 1, e.g. 0.3).",
)
@click.option(
    "--rolling-shutter",
    "rolling_shutter_s",
    type=click.FloatRange(0, None),
    default=0.0,
    show_default=True,
    help="Video rows read over this many seconds (rolling shutter, e.g. 0.03); 0: global.",
)
@click.option(
    "--workers",
    type=click.IntRange(0, 64),
    default=0,
    show_default=True,
    help="Rendering processes (0: one per core, at most 2).",
)
def simulate_command(
    scenario: str,
    out_dir: Path,
    seed: int,
    steps: int | None,
    survey: str,
    video_seconds: float | None,
    width: int,
    height: int,
    fps: float,
    flight: str | None,
    altitude_m: float | None,
    speed_m_s: float | None,
    flights_per_step: int,
    random_slides: int,
    slides: bool,
    gnss: str,
    log_time_offset_s: float,
    csv_units: str,
    cross_pattern: bool,
    sun_elevation_deg: float | None,
    light_gain: float,
    ground_contrast: float,
    rolling_shutter_s: float,
    workers: int,
) -> None:
    """Simulate drone surveys of landslides with known truth."""
    from worker.simulator.simulate import SimulationOptions, simulate_scenario

    opts = SimulationOptions(
        seed=seed,
        steps=steps,
        survey=survey,
        video_seconds=video_seconds,
        width=width,
        height=height,
        fps=fps,
        flight=flight,
        altitude_m=altitude_m,
        speed_m_s=speed_m_s,
        flights_per_step=flights_per_step,
        slides=slides,
        random_slides=random_slides,
        gnss=gnss,
        log_time_offset_s=log_time_offset_s,
        csv_units=csv_units,
        workers=workers,
        cross_pattern=cross_pattern,
        sun_elevation_deg=sun_elevation_deg,
        light_gain=light_gain,
        ground_contrast=ground_contrast,
        rolling_shutter_s=rolling_shutter_s,
    )
    t0 = time.perf_counter()
    last = [-1]

    def progress(f: float) -> None:
        pct = int(f * 100)
        if pct // 10 != last[0]:
            last[0] = pct // 10
            click.echo(f"  {pct:3d} %  ({time.perf_counter() - t0:.0f} s)", err=True)

    try:
        manifest = simulate_scenario(scenario, out_dir, opts, progress=progress)
    except ValueError as exc:
        click.echo(f"error: {exc}", err=True)
        raise SystemExit(EXIT_INPUT_ERROR) from exc
    d = manifest.data
    summary = {
        "manifest": str(manifest.path),
        "steps": len(d["steps"]),
        "surveys": sum(len(s["surveys"]) for s in d["steps"]),
        "events": sum(len(s["events"]) for s in d["steps"]),
        "max_relative_volume_error": d["volume_conservation"]["max_relative_error"],
        "render_cpu_ms_per_frame": d["rendering"]["cpu_ms_per_frame"],
        "seconds": round(time.perf_counter() - t0, 1),
    }
    click.echo(json.dumps(summary, indent=2))
