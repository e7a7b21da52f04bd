"""What the photo-set benchmarks share: the GNSS models they draw from (the fitted
and the held-out one), the outlier-flag counts, and the median / p90 / worst summaries
(`slidewatch bench photos`, worker/commands/bench_photos.py and bench_photos_full.py)."""

from __future__ import annotations

from typing import Any

import numpy as np

from worker.simulator.gnss import GnssErrorModel
from worker.simulator.gnss_field import FieldGnssModel

PLANTED_M = 10.0  # an outlier fix this far off (horizontally) counts as planted
MODERATE_M = 1.0  # a gross error between this and PLANTED_M is "moderate", below "clean"
TARGET_M = 3.0  # the target: residuals below 3 m RMS horizontally
MODELS = ("consumer", "field")
LABELS = {
    "consumer": "fitted: the robust fit's constants were chosen on it",
    "field": "held out: nothing in the pipeline was tuned on it",
}


def model_of(name: str) -> GnssErrorModel | FieldGnssModel:
    """The GNSS error model `name` (consumer or field)."""
    return FieldGnssModel() if name == "field" else GnssErrorModel.named(name)


def rms(d: np.ndarray) -> tuple[float, float]:
    """Horizontal and vertical RMS of (n, 3) errors."""
    return (
        float(np.sqrt((d[:, :2] ** 2).sum(axis=1).mean())),
        float(np.sqrt((d[:, 2] ** 2).mean())),
    )


def flag_counts(flagged: set[str], names: list[str], gross: np.ndarray) -> dict[str, Any]:
    """Flags against the photos' gross GPS errors (m, horizontal): planted beyond
    PLANTED_M, moderate between MODERATE_M and PLANTED_M (a time-tag slip at 8 m/s, the
    edge of a multipath zone: off, if by less than the line), clean below MODERATE_M."""
    planted = {n for n, g in zip(names, gross, strict=True) if g > PLANTED_M}
    moderate = {n for n, g in zip(names, gross, strict=True) if MODERATE_M < g <= PLANTED_M}
    return {
        "planted": len(planted),
        "moderate": len(moderate),
        "flagged": len(flagged),
        "flagged_planted": len(flagged & planted),
        "flagged_moderate": len(flagged & moderate),
        "flagged_clean": len(flagged - planted - moderate),
    }


def summary(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=np.float64)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"median": float("nan"), "p90": float("nan"), "worst": float("nan")}
    return {
        "median": round(float(np.median(a)), 3),
        "p90": round(float(np.percentile(a, 90)), 3),
        "worst": round(float(a.max()), 3),
    }


def share_below(values: list[float], limit: float) -> float:
    return round(float(np.mean(np.asarray(values) < limit)), 3)


def outlier_figures(runs: list[dict[str, Any]]) -> dict[str, Any]:
    planted = sum(r["planted"] for r in runs)
    hits = sum(r["flagged_planted"] for r in runs)
    return {
        "planted": planted,
        "flagged": sum(r["flagged"] for r in runs),
        "flagged_and_planted": hits,
        "recall": round(hits / planted, 3) if planted else None,
        "moderate": sum(r["moderate"] for r in runs),
        "flagged_moderate": sum(r["flagged_moderate"] for r in runs),
        # Photos without a gross error flagged: the false alarms.
        "false_flags": sum(r["flagged_clean"] for r in runs),
        "sets_with_a_false_flag": sum(r["flagged_clean"] > 0 for r in runs),
        "sets_with_a_missed_outlier": sum(r["flagged_planted"] < r["planted"] for r in runs),
    }


def fmt(s: dict[str, float]) -> str:
    return f"{s['median']:.2f} / {s['p90']:.2f} / {s['worst']:.2f}"
