"""Runs summed up per method: per generator, over all generators, over held-out ones.

Aggregates pool the runs themselves (not per-generator figures), and each one names the
generators it covers. Percentiles are numpy's linear ones over the pairs:

- f1_p10 is the 10th percentile of the per-pair patch F1, i.e. the F1 that 90 % of the
  pairs reach ("p90" in the sense of a guarantee); f1_worst the lowest; pairs whose F1 is
  undefined (no positive cell at all) are left out of these.
- false alarms on twins: p90 is the 90th percentile (90 % of twins have fewer), worst
  the largest. Twin runs that failed are left out (nothing detected would flatter them).
- failed pair runs count as all slides missed and as no cell predicted.
- seconds: successful runs, pairs and twins alike.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from worker.detection_bench.metrics import DEPTH_CLASSES, SIZE_CLASSES, ratio


def percentile(values: Sequence[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


def median(values: Sequence[float]) -> float | None:
    return percentile(values, 50)


def found_total(slides: Iterable[dict[str, Any]]) -> dict[str, Any]:
    slides = list(slides)
    found = sum(1 for s in slides if s["found"])
    return {"found": found, "total": len(slides), "recall": ratio(found, len(slides))}


def pooled_cells(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    tp, fp, fn = (sum(r["patch"][k] for r in runs) for k in ("tp", "fp", "fn"))
    return {
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "precision": ratio(tp, tp + fp),
        "recall": ratio(tp, tp + fn),
        "f1": ratio(2 * tp, 2 * tp + fp + fn),
    }


def spread(values: Sequence[float]) -> dict[str, Any]:
    """median, p90 and worst (largest) of figures where less is better."""
    return {
        "median": median(values),
        "p90": percentile(values, 90),
        "worst": max(values) if values else None,
        "runs": len(values),
    }


def aggregate_runs(runs: Sequence[dict[str, Any]], generators: Sequence[str]) -> dict[str, Any]:
    """One method's runs on `generators` summed up (keys: see the module doc)."""
    covered = set(generators)
    runs = [r for r in runs if r["generator"] in covered]
    pair_runs = [r for r in runs if r["kind"] == "pair"]
    twin_runs = [r for r in runs if r["kind"] == "twin" and r["ok"]]
    ok_runs = [r for r in runs if r["ok"]]
    f1s = [r["patch"]["f1"] for r in pair_runs if r["patch"]["f1"] is not None]
    slides = [s for r in pair_runs for s in r["slides"]]
    found = [s for s in slides if s["found"]]
    area_errors = [abs(s["area_error"]) for s in found if s["area_error"] is not None]
    volume_errors = [abs(s["volume_error"]) for s in found if s["volume_error"] is not None]
    fa = "false_alarm"
    twin_fa = [r[fa]["false_alarm_m2_per_km2"] for r in twin_runs]
    pair_fa = [r[fa]["false_alarm_m2_per_km2"] for r in pair_runs if r["ok"]]
    surface_false = sum(r[fa]["surface_false_alarm_m2"] for r in ok_runs)
    surface_total = sum(r[fa]["surface_change_m2"] for r in ok_runs)
    seconds = [r["seconds"] for r in ok_runs]
    failed = [r for r in runs if not r["ok"]]
    return {
        "generators": list(generators),
        "pairs": len(pair_runs),
        "twins": sum(1 for r in runs if r["kind"] == "twin"),
        "f1_median": median(f1s),
        "f1_p10": percentile(f1s, 10),
        "f1_worst": min(f1s) if f1s else None,
        "f1_pairs": len(f1s),
        "pooled": pooled_cells(pair_runs),
        "slides": found_total(slides),
        "recall_by_depth_lod": {
            c: found_total(s for s in slides if s["depth_class"] == c) for c in DEPTH_CLASSES
        },
        "recall_by_size": {
            c: found_total(s for s in slides if s["size_class"] == c) for c in SIZE_CLASSES
        },
        "recall_deep_large": found_total(s for s in slides if s["deep_large"]),
        "twin_false_alarm_m2_per_km2": spread([v for v in twin_fa if v is not None]),
        "pair_false_alarm_m2_per_km2": spread([v for v in pair_fa if v is not None]),
        "surface_change": {
            "false_alarm_m2": surface_false,
            "surface_change_m2": surface_total,
            "share": ratio(surface_false, surface_total),
        },
        "area_error_abs_median": median(area_errors),
        "volume_error_abs_median": median(volume_errors),
        "seconds_per_pair": {
            "median": median(seconds),
            "mean": float(np.mean(seconds)) if seconds else None,
            "max": max(seconds) if seconds else None,
        },
        "failures": len(failed),
        "failed_runs": [{k: r[k] for k in ("generator", "seed", "kind", "error")} for r in failed],
    }


def aggregate_report(
    runs: Sequence[dict[str, Any]],
    methods: Sequence[str],
    generators: Sequence[str],
    held_out: Sequence[str],
) -> dict[str, Any]:
    """{method: {"by_generator": {name: ...}, "all": ..., "held_out": ... or None}}."""
    out: dict[str, Any] = {}
    for method in methods:
        mine = [r for r in runs if r["method"] == method]
        out[method] = {
            "by_generator": {g: aggregate_runs(mine, [g]) for g in generators},
            "all": aggregate_runs(mine, generators),
            "held_out": aggregate_runs(mine, held_out) if held_out else None,
        }
    return out


__all__ = ["aggregate_report", "aggregate_runs"]
