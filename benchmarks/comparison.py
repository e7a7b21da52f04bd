"""Benchmark of the DSM comparison on a synthetic pair with a planted slide and a shift.

Usage: .venv/bin/python benchmarks/comparison.py --size 2000 --json OUT.json
Prints and writes wall time per stage and in total, the shift error (m and px) and the
area and volume errors (%) of all detections together against the planted truth.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from worker.pipeline.comparison import ComparisonOptions, run_stage, stages_for
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair


def run(
    size: int,
    pixel_size_m: float,
    shift: tuple[float, float, float],
    noise_m: float,
    seed: int,
    work_dir: Path,
) -> dict:
    pair = make_dsm_pair((size, size), pixel_size_m, shift, True, noise_m, seed)
    paths = write_dsm_pair(pair, work_dir / "input")
    options = ComparisonOptions()
    stage_seconds: dict[str, float] = {}
    results: dict[str, dict] = {}
    total_start = time.perf_counter()
    for stage in stages_for(options.method):
        start = time.perf_counter()
        results[stage] = run_stage(stage, paths.pre, paths.post, work_dir / "work", options)
        stage_seconds[stage] = round(time.perf_counter() - start, 3)
    total = time.perf_counter() - total_start

    truth = pair.truth
    assert truth is not None
    detections = json.loads((work_dir / "work" / "detections.geojson").read_text())["features"]
    found = {
        key: sum(f["properties"][key] for f in detections)
        for key in ("area_m2", "volume_loss_m3", "volume_gain_m3")
    }
    coreg = results["coregister"]
    # The coregistration reports the correction, the opposite of the simulated shift.
    error_m = [
        coreg["shift_east_m"] + shift[0],
        coreg["shift_north_m"] + shift[1],
        coreg["shift_up_m"] + shift[2],
    ]

    def pct(value: float, reference: float) -> float:
        return round(100.0 * (value - reference) / reference, 3)

    return {
        "size": size,
        "pixel_size_m": pixel_size_m,
        "shift_m": list(shift),
        "noise_m": noise_m,
        "seconds": {**stage_seconds, "total": round(total, 3)},
        "shift_error_m": {
            "east": round(error_m[0], 4),
            "north": round(error_m[1], 4),
            "up": round(error_m[2], 4),
        },
        "shift_error_px": {
            "east": round(error_m[0] / pixel_size_m, 4),
            "north": round(error_m[1] / pixel_size_m, 4),
        },
        "detections": len(detections),
        "area_error_pct": pct(found["area_m2"], truth.area_m2),
        "volume_loss_error_pct": pct(found["volume_loss_m3"], truth.volume_loss_m3),
        "volume_gain_error_pct": pct(found["volume_gain_m3"], truth.volume_gain_m3),
        "truth": {
            "area_m2": truth.area_m2,
            "volume_loss_m3": round(truth.volume_loss_m3, 1),
            "volume_gain_m3": round(truth.volume_gain_m3, 1),
        },
        "nmad_after_m": round(coreg["nmad_after_m"], 4),
        "lod_m": round(results["difference"]["lod_m"], 4),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2000, help="rows and columns")
    parser.add_argument("--pixel-size", type=float, default=1.0, help="metres")
    parser.add_argument(
        "--shift",
        type=float,
        nargs=3,
        default=(2.7, -1.35, 0.6),
        metavar=("EAST", "NORTH", "UP"),
        help="simulated shift of post, m",
    )
    parser.add_argument("--noise", type=float, default=0.05, help="DSM noise, m")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    parser.add_argument("--work-dir", type=Path, help="keep the rasters here")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="slidewatch-bench-") as tmp:
        work = args.work_dir or Path(tmp)
        figures = run(args.size, args.pixel_size, tuple(args.shift), args.noise, args.seed, work)
    text = json.dumps(figures, indent=2)
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
