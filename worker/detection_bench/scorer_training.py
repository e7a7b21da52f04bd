"""Train, calibrate and card the `scored` method's scorer on pair generators.

Generators are kept apart (leave generators out): the logistic model is fitted on the
candidates of `training` generators, its Platt calibration and the operating threshold
are chosen on `calibration` generators, and the card reports calibration (reliability
diagram, expected calibration error) on those and on every other generator, none of
which it saw.

A candidate (scoring.candidate_regions on the comparison's first three stages) is a
landslide when at least `positive_overlap` of its pixels lie on a planted slide.
The threshold is chosen for recall first: the highest probability at which the
calibration generators keep `target_recall` of their landslide candidates, capped at
0.5 so that a candidate more likely a landslide than not is always reported.
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.warp
from rasterio.enums import Resampling
from scipy import optimize

from worker.detection_bench.runner import PairGenerator, ensure_written
from worker.pairgen.pair import PAIR_CRS, TRUTH_JSON
from worker.pipeline import comparison
from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.change_regions import (
    describe_region,
    label_regions,
    load_change_rasters,
    significant_regions,
)
from worker.pipeline.scorer import Scorer, logit_of
from worker.pipeline.scoring import ScoreOptions, area_significant

TRAITS = (
    "log_area_px",
    "log_area_correlation",
    "mean_lod_ratio",
    "p90_lod_ratio",
    "significant_share",
    "log_area_z",
    "balance",
    "sign_coherence",
    "object_share",
    "ground_motion_share",
    "ring_significant_share",
    "log_elongation",
    "compactness",
    "downslope_alignment",
)
FIRST_STAGES = ("align", "coregister", "difference")


@dataclass
class Candidates:
    traits: list[dict[str, float]]
    labels: np.ndarray  # 1 landslide, 0 not
    generators: list[str]

    def matrix(self, names: Sequence[str] = TRAITS) -> np.ndarray:
        return np.array([[t[n] for n in names] for t in self.traits], dtype=float).reshape(
            -1, len(names)
        )

    def subset(self, generators: Sequence[str]) -> Candidates:
        keep = [i for i, g in enumerate(self.generators) if g in set(generators)]
        return Candidates(
            [self.traits[i] for i in keep], self.labels[keep], [self.generators[i] for i in keep]
        )


def collect_candidates(
    work_dir: Path,
    generators: Sequence[PairGenerator],
    seeds: Sequence[int],
    options: ScoreOptions | None = None,
    log: Callable[[str], Any] = print,
    positive_overlap: float = 0.3,
) -> Candidates:
    """Every candidate of every pair and twin, with its traits and truth label."""
    options = options or ScoreOptions()
    traits: list[dict[str, float]] = []
    labels: list[int] = []
    names: list[str] = []
    for generator in generators:
        for seed in seeds:
            for kind in ("pair", "twin"):
                folder = Path(work_dir) / "pairs" / generator.name / f"seed{seed}" / kind
                if not (folder / TRUTH_JSON).exists():
                    ensure_written(generator.make(seed, no_change=kind == "twin"), folder)
                run = Path(work_dir) / "candidates" / generator.name / f"seed{seed}" / kind
                found = _pair_candidates(folder, run, options, positive_overlap)
                for region_traits, label in found:
                    traits.append(region_traits)
                    labels.append(label)
                    names.append(generator.name)
                n = len(found)
                log(f"{generator.name} seed {seed} {kind}: {n} candidates")
    return Candidates(traits, np.asarray(labels, dtype=int), names)


def _pair_candidates(
    folder: Path, run: Path, options: ScoreOptions, positive_overlap: float
) -> list[tuple[dict[str, float], int]]:
    """(traits, label) of one written pair's candidates; cached in run/candidates.json."""
    cache = run / "candidates.json"
    if cache.exists():
        cached = json.loads(cache.read_text())
        # Traits computed by an older version of change_regions are computed again.
        if cached and set(cached[0]["traits"]) >= set(TRAITS):
            return [(c["traits"], int(c["label"])) for c in cached]
        if not cached and (run / comparison.DH).exists():
            return []
    opts = comparison.ComparisonOptions(method="threshold")
    for stage in FIRST_STAGES:
        comparison.run_stage(stage, folder / "pre.tif", folder / "post.tif", run, opts)
    rasters = load_change_rasters(
        run / comparison.DH,
        run / comparison.SIGNIFICANCE,
        run / comparison.PRE_ALIGNED,
        run / comparison.POST_COREGISTERED,
    )
    truth = _truth_on(folder / "truth.tif", run / comparison.DH)
    mask = significant_regions(rasters, options) | area_significant(rasters, options)
    grid_labels, keep, windows = label_regions(mask, rasters, options)
    found = []
    for label, window in zip(keep, windows, strict=True):
        region = describe_region(rasters, grid_labels, label, window, options)
        inside = grid_labels[window] == label
        on_slide = np.count_nonzero(inside & (truth[window] > 0))
        found.append((region.traits, int(on_slide >= positive_overlap * np.count_nonzero(inside))))
    write_text_atomic(cache, json.dumps([{"traits": t, "label": label} for t, label in found]))
    return found


def fit_logistic(
    x: np.ndarray, y: np.ndarray, l2: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(mean, scale, coefficients, intercept) of an L2 logistic fit, classes balanced."""
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale[scale < 1e-9] = 1.0
    z = (x - mean) / scale
    positives = max(int(y.sum()), 1)
    negatives = max(int(len(y) - y.sum()), 1)
    weights = np.where(y == 1, len(y) / (2 * positives), len(y) / (2 * negatives))

    def loss(params: np.ndarray) -> tuple[float, np.ndarray]:
        w, b = params[:-1], params[-1]
        t = z @ w + b
        p = 1 / (1 + np.exp(-np.clip(t, -50, 50)))
        ll = weights * (np.logaddexp(0, t) - y * t)
        grad_t = weights * (p - y)
        value = float(ll.sum() / len(y) + 0.5 * l2 * np.sum(w * w) / len(y))
        grad = np.concatenate([z.T @ grad_t / len(y) + l2 * w / len(y), [grad_t.sum() / len(y)]])
        return value, grad

    result = optimize.minimize(loss, np.zeros(z.shape[1] + 1), jac=True, method="L-BFGS-B")
    return mean, scale, result.x[:-1], float(result.x[-1])


def fit_platt(logits: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """a, b of p = sigmoid(a * logit + b) by maximum likelihood (Platt scaling)."""

    def loss(params: np.ndarray) -> float:
        t = params[0] * logits + params[1]
        return float(np.sum(np.logaddexp(0, t) - y * t))

    result = optimize.minimize(loss, np.array([1.0, 0.0]), method="Nelder-Mead")
    return float(result.x[0]), float(result.x[1])


def reliability(p: np.ndarray, y: np.ndarray, bins: int = 10) -> dict[str, Any]:
    """Reliability diagram (per probability bin: count, mean score, share true) and ECE."""
    edges = np.linspace(0, 1, bins + 1)
    rows = []
    ece = 0.0
    for i in range(bins):
        sel = (p >= edges[i]) & ((p < edges[i + 1]) if i < bins - 1 else (p <= 1))
        if not sel.any():
            continue
        mean_p, share = float(p[sel].mean()), float(y[sel].mean())
        rows.append(
            {
                "bin": [round(edges[i], 2), round(edges[i + 1], 2)],
                "count": int(sel.sum()),
                "mean_score": round(mean_p, 3),
                "share_landslide": round(share, 3),
            }
        )
        ece += sel.sum() / len(p) * abs(mean_p - share)
    return {"bins": rows, "ece": round(float(ece), 4), "candidates": len(p)}


def recall_first_threshold(p: np.ndarray, y: np.ndarray, target_recall: float) -> float:
    """The highest threshold keeping `target_recall` of the positives, at most 0.5."""
    positives = np.sort(p[y == 1])
    if positives.size == 0:
        return 0.5
    index = int(np.floor((1 - target_recall) * positives.size))
    return float(min(positives[min(index, positives.size - 1)] - 1e-6, 0.5))


def train_scorer(
    candidates: Candidates,
    training: Sequence[str],
    calibration: Sequence[str],
    target_recall: float = 0.98,
    name: str = "scorer-default",
) -> Scorer:
    """Fit on `training`, calibrate and choose the threshold on `calibration`."""
    fit = candidates.subset(training)
    cal = candidates.subset(calibration)
    if fit.labels.sum() == 0 or cal.labels.sum() == 0:
        raise ValueError("both the training and the calibration sets need landslide candidates")
    mean, scale, coefficients, intercept = fit_logistic(fit.matrix(), fit.labels)
    raw = Scorer(
        name=name,
        version=dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ"),
        traits=TRAITS,
        mean=mean,
        scale=scale,
        coefficients=coefficients,
        intercept=intercept,
        calibration=(1.0, 0.0),
        threshold=0.5,
        card={},
    )
    a, b = fit_platt(raw.logit(cal.traits), cal.labels)
    calibrated = Scorer(**{**raw.__dict__, "calibration": (a, b)})
    p_cal = calibrated.probability(cal.traits)
    threshold = recall_first_threshold(p_cal, cal.labels, target_recall)
    held = sorted(set(candidates.generators) - set(training) - set(calibration))
    card = {
        "model": "logistic regression over region traits, Platt-calibrated",
        "training_generators": list(training),
        "calibration_generators": list(calibration),
        "held_out_generators": held,
        "training_candidates": {"total": len(fit.labels), "landslide": int(fit.labels.sum())},
        "threshold_rule": f"highest probability keeping {target_recall:.0%} of the calibration "
        "generators' landslide candidates, at most 0.5 (recall first)",
        "logit_offset_of_threshold": round(logit_of(threshold), 3),
        "reliability_calibration": reliability(p_cal, cal.labels),
        "reliability_by_generator": {
            g: reliability(calibrated.probability(sub.traits), sub.labels)
            for g in sorted(set(candidates.generators))
            if len((sub := candidates.subset([g])).labels)
        },
    }
    return Scorer(**{**calibrated.__dict__, "threshold": threshold, "card": card})


def save_scorer(scorer: Scorer, path: Path) -> None:
    write_text_atomic(Path(path), json.dumps(scorer.to_dict(), indent=1))


def _truth_on(truth_path: Path, grid_path: Path) -> np.ndarray:
    """The truth slide ids resampled (nearest) onto the comparison's grid."""
    with rasterio.open(grid_path) as grid, rasterio.open(truth_path) as src:
        out = np.zeros((grid.height, grid.width), dtype=np.uint8)
        rasterio.warp.reproject(
            src.read(1),
            out,
            src_transform=src.transform,
            src_crs=src.crs or PAIR_CRS,
            dst_transform=grid.transform,
            dst_crs=grid.crs,
            resampling=Resampling.nearest,
        )
    return out
