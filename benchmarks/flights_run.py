"""The many-flight benchmark in one call: flights (benchmarks/flights.py), their summary
(benchmarks/flights_summary.py), the JSON file and the printed table.

    slidewatch bench reconstruction --flights 20 --json OUT.json [--scenario hillslope]
        [--video-seconds S] [--first-seed 1] [--sfm-every 5]

The JSON is written again after every flight, so an interrupted run keeps its flights.
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from flights import SCENARIOS, FixedConditions, FlightSettings, run_flights
from flights_summary import TARGETS, by_condition, condition_table, summarize, table
from reconstruction import warm_imports

from worker.pipeline.atomic import write_text_atomic


def run(
    json_path: Path,
    work_dir: Path,
    seeds: list[int],
    scenarios: tuple[str, ...] = (),
    video_seconds: float | None = None,
    video: tuple[int, int, float] = (640, 360, 30.0),
    sfm_every: int = 5,
    fixed: FixedConditions | None = None,
    readout_given: bool = True,
    from_stage: str | None = None,
) -> dict[str, Any]:
    """Run the flights of `seeds` and write the report; returns it with its table.
    `fixed`: what every flight holds the same instead of drawing it; `readout_given`:
    a rolling-shutter flight's readout is given to the pipeline; `from_stage`: reuse
    the reconstructions in `work_dir` up to that stage (FlightSettings)."""
    width, height, fps = video
    settings = FlightSettings(
        width=width,
        height=height,
        fps=fps,
        video_seconds=(video_seconds, video_seconds) if video_seconds else (20.0, 30.0),
        readout_given=readout_given,
        from_stage=from_stage,
    )
    warm_imports()
    report: dict[str, Any] = {
        "machine": {"platform": platform.platform(), "python": platform.python_version()},
        "settings": {
            "seeds": seeds,
            "scenarios": list(scenarios or SCENARIOS),
            "sfm_every": sfm_every,
            "width": width,
            "height": height,
            "fps": fps,
            "video_seconds": list(settings.video_seconds),
            "readout_given": readout_given,
            "from_stage": from_stage,
            "fixed": asdict(fixed or FixedConditions()),
        },
        "targets": [t.__dict__ for t in TARGETS],
    }
    start = time.perf_counter()

    def save(records: list[dict[str, Any]]) -> None:
        report["flights"] = records
        report["summary"] = summarize(records)
        report["by_condition"] = by_condition(records)
        report["seconds"] = round(time.perf_counter() - start, 1)
        json_path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(json_path, json.dumps(report, indent=2))
        print(f"flight {len(records)}/{len(seeds)}: {_line(records[-1])}", flush=True)

    run_flights(seeds, work_dir, settings, tuple(scenarios or SCENARIOS), sfm_every, save, fixed)
    report["table"] = table(report["summary"]) + "\n" + condition_table(report["by_condition"])
    return report


def _line(record: dict[str, Any]) -> str:
    c = record["conditions"]
    head = f"seed {c['seed']} {c['scenario']} {c['gnss']} {c['plan']} {c['altitude_m']} m"
    if c.get("drawn"):
        head += f" ({', '.join(c['drawn'])})"
    if not record["success"]:
        return f"{head}: failed ({record['slam']['failure']['message'][:100]})"
    slam = record["slam"]
    nmad = slam["dsm_nmad_as_georeferenced_px"]
    nmad_text = "-" if nmad is None else f"{nmad:.2f}"
    wall = slam["wall_seconds"]
    took = f"from {slam['reused_before']} on" if wall is None else f"{wall:.0f} s"
    return (
        f"{head}: NMAD {nmad_text} px as georeferenced, "
        f"{slam['dsm_nmad_coregistered_px']:.2f} px co-registered, {took}"
    )
