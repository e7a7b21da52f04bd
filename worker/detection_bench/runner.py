"""Run every detection method on generated pairs and their no-change twins, and score.

Layout of `work_dir` (pairs are kept, so a second run does not write them again):

    pairs/<generator>/seed<k>/pair/   pre.tif post.tif truth.tif truth.json
    pairs/<generator>/seed<k>/twin/   the same without slides (no_change=True)
    runs/<generator>/seed<k>/<pair|twin>/<method>/   the comparison's files

One pair is in memory at a time. A method that raises on a pair is recorded (its error
text) and scored as if it had detected nothing: all slides missed; its twin run is left
out of the false-alarm figures (nothing detected there would flatter it); the tables
count the failures. The benchmark itself goes on.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

from worker.detection_bench.aggregate import aggregate_report
from worker.detection_bench.detections import GridDetections, read_detections
from worker.detection_bench.metrics import lod_m, score_pair
from worker.detection_bench.tables import format_tables
from worker.pairgen.pair import PAIR_CRS, TRUTH_JSON, DsmPair, PairUnavailable
from worker.pipeline import comparison
from worker.pipeline.detection_methods import method_names
from worker.pipeline.methods.threshold import BASELINE_OPTIONS

KINDS = ("pair", "twin")
DEFAULT_WORK_DIR = Path("data/bench-detection-generators")


class PairGenerator(Protocol):
    name: str

    def make(self, seed: int, no_change: bool = False) -> DsmPair: ...


def available_generators(work_dir: Path | None = None) -> Mapping[str, PairGenerator]:
    """The pair generators (worker/pairgen/), the survey simulator's analytic pairs and
    the DSMs reconstructed from its video (cached under `work_dir`/reconstructed)."""
    from worker.detection_bench.reconstructed_pairs import ReconstructedPairs
    from worker.detection_bench.simulator_pairs import SimulatorPairs
    from worker.pairgen import GENERATORS

    simulator = SimulatorPairs()
    video = ReconstructedPairs(Path(work_dir or DEFAULT_WORK_DIR) / "reconstructed")
    return {**GENERATORS, simulator.name: simulator, video.name: video}


def resolve_generators(
    names: Sequence[str] | None = None, work_dir: Path | None = None
) -> list[PairGenerator]:
    """Generators by name through the registry; all of them when `names` is empty."""
    registry = available_generators(work_dir)
    if not names:
        return list(registry.values())
    unknown = [n for n in names if n not in registry]
    if unknown:
        raise ValueError(
            f"unknown generator {', '.join(unknown)}; available: {', '.join(registry)}"
        )
    return [registry[n] for n in names]


def default_held_out(names: Sequence[str]) -> list[str]:
    """Generators the shipped scorer was not fitted or calibrated on, among `names`."""
    from worker.pipeline.scorer import training_generators

    fitted = set(training_generators())
    return [name for name in names if name not in fitted]


# Benchmark-only variants of a method: the simple baseline the default must never be
# worse than is the LoD method with one NMAD for the whole raster and no volume test;
# "threshold-nofloor" is the per-pixel LoD alone (what the default's floor at the
# baseline's LoD costs), "threshold-noflanks" the floor without the flanks that join
# significant change, "threshold-novolume" the default without its volume test,
# "threshold-owncontext" the context rule measured from the default's own regions,
# "threshold-cut" the default with mown grass set aside (an option, off by default),
# "threshold-nofringe" the default's regions without the edge the baseline draws.
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "threshold-uniform": ("threshold", BASELINE_OPTIONS),
    "threshold-nofloor": ("threshold", {"difference": {"uniform_floor": False}}),
    "threshold-noflanks": ("threshold", {"difference": {"flank_area_z": None}}),
    "threshold-novolume": ("threshold", {"vectorize": {"min_volume_z": None}}),
    "threshold-owncontext": ("threshold", {"vectorize": {"context_by_baseline": False}}),
    "threshold-cut": ("threshold", {"vectorize": {"vegetation_cut": True}}),
    "threshold-nofringe": ("threshold", {"vectorize": {"baseline_fringe_px": 0}}),
}


def validate_methods(methods: Sequence[str]) -> list[str]:
    """Methods checked against the comparison's list as it is now (methods get added),
    plus the benchmark's variants (VARIANTS)."""
    known = (*method_names(), *VARIANTS)
    unknown = [m for m in methods if m not in known]
    if unknown or not methods:
        raise ValueError(
            f"unknown detection method {', '.join(unknown) or '(none given)'}; "
            f"available: {', '.join(known)}"
        )
    return list(dict.fromkeys(methods))


def validate_held_out(held_out: Sequence[str], names: Sequence[str]) -> list[str]:
    """Held-out names must be among the benchmarked generators (a typo would otherwise
    silently empty the held-out row)."""
    unknown = [n for n in held_out if n not in names]
    if unknown:
        raise ValueError(
            f"held-out generator {', '.join(unknown)} is not benchmarked; "
            f"benchmarked: {', '.join(names)}"
        )
    return [n for n in names if n in set(held_out)]


def method_options(
    method: str, options_by_method: Mapping[str, Any] | None
) -> comparison.ComparisonOptions:
    """ComparisonOptions for a method: the caller's (an instance or a dict) or defaults."""
    given = (options_by_method or {}).get(method)
    if given is None and method in VARIANTS:
        base, overrides = VARIANTS[method]
        return comparison.ComparisonOptions.from_dict({**overrides, "method": base})
    if given is None:
        return comparison.ComparisonOptions(method=method)
    if isinstance(given, comparison.ComparisonOptions):
        return dataclasses.replace(given, method=method)
    return comparison.ComparisonOptions.from_dict({**dict(given), "method": method})


def ensure_written(pair: DsmPair, folder: Path) -> bool:
    """Write the pair unless a complete copy is there; True when written now.

    Written into a sibling folder renamed into place, so an interrupted write never
    looks complete to the next run.
    """
    if (folder / TRUTH_JSON).exists():
        return False
    partial = folder.with_name(folder.name + ".part")
    shutil.rmtree(partial, ignore_errors=True)
    pair.write(partial)
    shutil.rmtree(folder, ignore_errors=True)
    os.replace(partial, folder)
    return True


def run_method(
    pair: DsmPair, folder: Path, run_dir: Path, options: comparison.ComparisonOptions
) -> dict[str, Any]:
    """One comparison on one written pair, scored; a raising method is recorded."""
    # Outputs of an earlier run must not be scored as this run's.
    shutil.rmtree(run_dir, ignore_errors=True)
    start = time.perf_counter()
    try:
        result = comparison.compare_dsms(folder / "pre.tif", folder / "post.tif", run_dir, options)
        detections = read_detections(result.detections_path, pair.transform, pair.shape, PAIR_CRS)
    except Exception as exc:  # any failure is a result of the benchmark, not its end
        return failed_run(pair, exc)
    seconds = time.perf_counter() - start
    return {
        "ok": True,
        "error": None,
        "seconds": seconds,
        # What the method itself measured: its LoD and the co-registration shift.
        "comparison": {
            **result.summary(),
            "lod_m": result.results.get("difference", {}).get("lod_m"),
        },
        **score_pair(pair, detections),
    }


def failed_run(pair: DsmPair, exc: Exception) -> dict[str, Any]:
    """A run whose method raised: its error, scored as if nothing was detected."""
    return {
        "ok": False,
        "error": f"{type(exc).__name__}: {exc}",
        "seconds": None,
        "comparison": None,
        **score_pair(pair, GridDetections.empty(pair.shape)),
    }


def pair_record(pair: DsmPair, kind: str) -> dict[str, Any]:
    return {
        "generator": pair.generator,
        "seed": pair.seed,
        "kind": kind,
        "pixel_size": pair.pixel_size,
        "shape": list(pair.shape),
        "slides": len(pair.slides),
        "error_nmad_m": pair.error_nmad_m,
        "lod_m": lod_m(pair),
    }


def run_generator_benchmark(
    work_dir: Path,
    generators: Sequence[PairGenerator],
    methods: Sequence[str],
    seeds: Sequence[int],
    options_by_method: Mapping[str, Any] | None = None,
    log: Callable[[str], Any] = print,
    held_out: Sequence[str] = (),
) -> dict[str, Any]:
    """Every method on every generator's pairs and twins; the report (JSON-able).

    `held_out`: generators no method was fitted to; they get their own aggregate.
    """
    methods = validate_methods(methods)
    names = [g.name for g in generators]
    held_out = validate_held_out(held_out, names)
    options = {m: method_options(m, options_by_method) for m in methods}
    work_dir = Path(work_dir)
    pairs: list[dict[str, Any]] = []
    runs: list[dict[str, Any]] = []
    unavailable: list[dict[str, Any]] = []
    for generator in generators:
        for seed in seeds:
            for kind in KINDS:
                # Only this pair is alive: the previous one is dropped before making it.
                try:
                    pair = generator.make(seed, no_change=kind == "twin")
                except PairUnavailable as exc:
                    unavailable.append(
                        {
                            "generator": generator.name,
                            "seed": seed,
                            "kind": kind,
                            "reason": str(exc),
                        }
                    )
                    log(f"{generator.name} seed{seed} {kind}: no pair ({exc})")
                    continue
                folder = work_dir / "pairs" / generator.name / f"seed{seed}" / kind
                ensure_written(pair, folder)
                pairs.append(pair_record(pair, kind))
                for method in methods:
                    run_dir = work_dir / "runs" / generator.name / f"seed{seed}" / kind / method
                    run = {"generator": generator.name, "seed": seed, "kind": kind}
                    run |= {"method": method, **run_method(pair, folder, run_dir, options[method])}
                    runs.append(run)
                    log(describe_run(run))
                del pair
    report: dict[str, Any] = {
        "suite": "generators",
        "generators": names,
        "methods": methods,
        "seeds": list(seeds),
        "held_out": held_out,
        "pairs": pairs,
        "unavailable_pairs": unavailable,
        "runs": runs,
    }
    report["aggregates"] = aggregate_report(runs, methods, names, report["held_out"])
    return report


def report_json(report: dict[str, Any]) -> str:
    """The report as strict JSON: NaN and infinities (a degenerate pair's NMAD) as null."""

    def clean(value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            return [clean(v) for v in value]
        return value

    return json.dumps(clean(report), indent=1, allow_nan=False)


def describe_run(run: dict[str, Any]) -> str:
    head = f"{run['generator']} seed{run['seed']} {run['kind']} {run['method']}"
    if not run["ok"]:
        return f"{head}: FAILED {run['error']}"
    found = sum(s["found"] for s in run["slides"])
    f1 = run["patch"]["f1"]
    fa = run["false_alarm"]["false_alarm_m2_per_km2"]
    return (
        f"{head}: F1 {'-' if f1 is None else f'{f1:.3f}'}, slides {found}/{len(run['slides'])},"
        f" false alarms {'-' if fa is None else f'{fa:.0f}'} m2/km2 ({run['seconds']:.1f} s)"
    )


__all__ = [
    "PairGenerator",
    "available_generators",
    "default_held_out",
    "format_tables",
    "report_json",
    "resolve_generators",
    "run_generator_benchmark",
    "validate_held_out",
    "validate_methods",
]
