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
from dataclasses import dataclass, field
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
    SURFACE_CHANGE,
    describe_region,
    label_regions,
    load_change_rasters,
    significant_regions,
)
from worker.pipeline.difference import ERROR_MODEL_FILE
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
    "edge_contrast",
)
FIRST_STAGES = ("align", "coregister", "difference")


@dataclass
class Candidates:
    """Candidates of many pairs: traits, labels, and what each covers of each slide."""

    traits: list[dict[str, float]]
    labels: np.ndarray  # 1 landslide, 0 not
    generators: list[str]
    pairs: list[str] = field(default_factory=list)  # "generator/seed/kind" per candidate
    cover: list[dict[str, int]] = field(default_factory=list)  # slide id -> pixels
    lod_cover: list[dict[str, int]] = field(default_factory=list)  # ... within the LoD mask
    surface: list[bool] = field(default_factory=list)  # set aside as a surface change
    slides: dict[str, dict[str, int]] = field(default_factory=dict)  # pair -> id -> pixels

    def matrix(self, names: Sequence[str] = TRAITS) -> np.ndarray:
        return np.array([[t[n] for n in names] for t in self.traits], dtype=float).reshape(
            -1, len(names)
        )

    def subset(self, generators: Sequence[str]) -> Candidates:
        wanted = set(generators)
        keep = [i for i, g in enumerate(self.generators) if g in wanted]
        return Candidates(
            [self.traits[i] for i in keep],
            self.labels[keep],
            [self.generators[i] for i in keep],
            [self.pairs[i] for i in keep],
            [self.cover[i] for i in keep],
            [self.lod_cover[i] for i in keep],
            [self.surface[i] for i in keep],
            {k: v for k, v in self.slides.items() if k.split("/")[0] in wanted},
        )

    def slide_recall(self, kept: np.ndarray, lod_only: bool = False) -> float | None:
        """Share of slides covered >= 25 % by the kept candidates (the benchmark's rule);
        `lod_only`: by their pixels within the LoD mask (what the LoD method reports)."""
        covered: dict[tuple[str, str], int] = {}
        for i in np.flatnonzero(kept):
            for slide, pixels in (self.lod_cover if lod_only else self.cover)[i].items():
                key = (self.pairs[i], slide)
                covered[key] = covered.get(key, 0) + pixels
        total = found = 0
        for pair, slides in self.slides.items():
            for slide, area in slides.items():
                total += 1
                found += covered.get((pair, slide), 0) >= 0.25 * area
        return found / total if total else None


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
    out = Candidates([], np.zeros(0, dtype=int), [])
    labels: list[int] = []
    for generator in generators:
        for seed in seeds:
            for kind in ("pair", "twin"):
                folder = Path(work_dir) / "pairs" / generator.name / f"seed{seed}" / kind
                if not (folder / TRUTH_JSON).exists():
                    ensure_written(generator.make(seed, no_change=kind == "twin"), folder)
                run = Path(work_dir) / "candidates" / generator.name / f"seed{seed}" / kind
                found = _pair_candidates(folder, run, options, positive_overlap)
                pair_id = f"{generator.name}/{seed}/{kind}"
                out.slides[pair_id] = found["slides"]
                for c in found["candidates"]:
                    out.traits.append(c["traits"])
                    labels.append(int(c["label"]))
                    out.generators.append(generator.name)
                    out.pairs.append(pair_id)
                    out.cover.append(c["cover"])
                    out.lod_cover.append(c["lod_cover"])
                    out.surface.append(bool(c["surface"]))
                log(f"{generator.name} seed {seed} {kind}: {len(found['candidates'])} candidates")
    out.labels = np.asarray(labels, dtype=int)
    return out


CACHE_VERSION = 2


def _pair_candidates(
    folder: Path, run: Path, options: ScoreOptions, positive_overlap: float
) -> dict[str, Any]:
    """One written pair's candidates (traits, label, slide cover) and its slides' sizes on
    the comparison's grid; cached in run/candidates.json."""
    cache = run / "candidates.json"
    if cache.exists():
        cached = json.loads(cache.read_text())
        # Candidates of an older version of the traits are computed again.
        if cached.get("version") == CACHE_VERSION and cached.get("traits") == list(TRAITS):
            return cached
    opts = comparison.ComparisonOptions(method="threshold")
    # The first stages' files are reused when complete (the difference stage writes its
    # error model last); a changed pipeline needs a fresh work dir.
    if not (run / ERROR_MODEL_FILE).exists():
        for stage in FIRST_STAGES:
            comparison.run_stage(stage, folder / "pre.tif", folder / "post.tif", run, opts)
    rasters = load_change_rasters(
        run / comparison.DH,
        run / comparison.SIGNIFICANCE,
        run / comparison.PRE_ALIGNED,
        run / comparison.POST_COREGISTERED,
    )
    truth = _truth_on(folder / "truth.tif", run / comparison.DH)
    lod_mask = significant_regions(rasters, options)
    mask = lod_mask | area_significant(rasters, options)
    grid_labels, keep, windows = label_regions(mask, rasters, options)
    ids, areas = np.unique(truth[truth > 0], return_counts=True)
    found: dict[str, Any] = {
        "version": CACHE_VERSION,
        "traits": list(TRAITS),
        "slides": {str(int(i)): int(a) for i, a in zip(ids, areas, strict=True)},
        "candidates": [],
    }
    for label, window in zip(keep, windows, strict=True):
        region = describe_region(rasters, grid_labels, label, window, options)
        inside = grid_labels[window] == label
        on = truth[window][inside]
        on_lod = truth[window][inside & lod_mask[window]]
        cover = {
            str(int(i)): int(n)
            for i, n in zip(*np.unique(on[on > 0], return_counts=True), strict=True)
        }
        lod_cover = {
            str(int(i)): int(n)
            for i, n in zip(*np.unique(on_lod[on_lod > 0], return_counts=True), strict=True)
        }
        found["candidates"].append(
            {
                "traits": region.traits,
                "label": int(sum(cover.values()) >= positive_overlap * np.count_nonzero(inside)),
                "cover": cover,
                "lod_cover": lod_cover,
                "surface": region.kind == SURFACE_CHANGE,
            }
        )
    write_text_atomic(cache, json.dumps(found))
    return found


# Traits whose direction is known from the physics: more of it is more (+1) or less (-1)
# landslide-like, whatever a few training generators happen to show. A building's wall
# under a misregistration is a large, sharp change; so is a scarp: the fit must tell them
# apart by what differs (an object with no ground motion), not learn that large, sharp
# changes are not landslides.
TRAIT_SIGNS = {
    "log_area_px": 1,
    "log_area_correlation": 1,
    "mean_lod_ratio": 1,
    "p90_lod_ratio": 1,
    "significant_share": 1,
    "log_area_z": 1,
    "object_share": -1,
    "ground_motion_share": 1,
    "downslope_alignment": 1,
    "edge_contrast": 1,
}


def fit_logistic(
    x: np.ndarray,
    y: np.ndarray,
    l2: float = 1.0,
    groups: Sequence[str] | None = None,
    signs: Sequence[int] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(mean, scale, coefficients, intercept) of an L2 logistic fit.

    Classes are balanced within each group (generator) and groups weigh alike, so one
    generator with many candidates does not set the rules; `signs` (+1, -1, 0 per column)
    bounds each coefficient's sign.
    """
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale[scale < 1e-9] = 1.0
    z = (x - mean) / scale
    weights = _balanced_weights(y, list(groups) if groups is not None else ["all"] * len(y))

    def loss(params: np.ndarray) -> tuple[float, np.ndarray]:
        w, b = params[:-1], params[-1]
        t = z @ w + b
        p = 1 / (1 + np.exp(-np.clip(t, -50, 50)))
        ll = weights * (np.logaddexp(0, t) - y * t)
        grad_t = weights * (p - y)
        value = float(ll.sum() / len(y) + 0.5 * l2 * np.sum(w * w) / len(y))
        grad = np.concatenate([z.T @ grad_t / len(y) + l2 * w / len(y), [grad_t.sum() / len(y)]])
        return value, grad

    bounds = [
        (0.0, None) if sign > 0 else (None, 0.0) if sign < 0 else (None, None)
        for sign in (signs if signs is not None else [0] * z.shape[1])
    ] + [(None, None)]
    result = optimize.minimize(
        loss, np.zeros(z.shape[1] + 1), jac=True, method="L-BFGS-B", bounds=bounds
    )
    return mean, scale, result.x[:-1], float(result.x[-1])


def _balanced_weights(y: np.ndarray, groups: list[str]) -> np.ndarray:
    """Weights summing to len(y): each group alike, each class alike within a group."""
    weights = np.zeros(len(y))
    names = sorted(set(groups))
    group_of = np.array(groups)
    for name in names:
        in_group = group_of == name
        classes = [c for c in (0, 1) if np.any(y[in_group] == c)]
        for c in classes:
            sel = in_group & (y == c)
            weights[sel] = len(y) / (len(names) * len(classes) * sel.sum())
    return weights


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


def slide_recall_threshold(
    cal: Candidates, p: np.ndarray
) -> tuple[float | None, dict[str, float | None]]:
    """The highest threshold (<= 0.5) whose slide recall on `cal` is at least the LoD
    method's, and both recalls; None when `cal` has no slide."""
    landslide_kind = ~np.asarray(cal.surface, dtype=bool)
    lod_recall = cal.slide_recall(landslide_kind, lod_only=True)
    if lod_recall is None:
        return None, {"lod": None, "scored": None}
    for t in sorted({0.5, *(float(v) for v in p if v < 0.5)}, reverse=True):
        recall = cal.slide_recall(landslide_kind & (p >= t))
        if recall is not None and recall >= lod_recall:
            return t, {"lod": round(lod_recall, 4), "scored": round(recall, 4)}
    return 0.0, {"lod": round(lod_recall, 4), "scored": cal.slide_recall(landslide_kind)}


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
    mean, scale, coefficients, intercept = fit_logistic(
        fit.matrix(),
        fit.labels,
        groups=fit.generators,
        signs=[TRAIT_SIGNS.get(name, 0) for name in TRAITS],
    )
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
    threshold, recalls = slide_recall_threshold(cal, p_cal)
    if threshold is None:  # no slide to calibrate on: keep the candidates' share instead
        threshold = recall_first_threshold(p_cal, cal.labels, target_recall)
    held = sorted(set(candidates.generators) - set(training) - set(calibration))
    card = {
        "model": "logistic regression over region traits, Platt-calibrated",
        "training_generators": list(training),
        "calibration_generators": list(calibration),
        "held_out_generators": held,
        "training_candidates": {"total": len(fit.labels), "landslide": int(fit.labels.sum())},
        "threshold_rule": "recall first: the highest probability, at most 0.5, at which the "
        "calibration generators' slides are found (>= 25 % covered) at least as often as "
        "by the LoD method's regions",
        "calibration_slide_recall": recalls,
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


def benchmark_figures(report: dict[str, Any]) -> dict[str, Any]:
    """Per-generator figures of the scored methods and the LoD methods, for the card."""
    out: dict[str, Any] = {
        "seeds": report["seeds"],
        "held_out": report["held_out"],
        "leave_one_out": report.get("leave_one_out"),
        "methods": {},
    }
    for method, aggregates in report["aggregates"].items():
        rows = {}
        for name, agg in {**aggregates["by_generator"], "all": aggregates["all"]}.items():
            fa = agg["twin_false_alarm_m2_per_km2"]
            rows[name] = {
                "f1_median": agg["f1_median"],
                "f1_p10": agg["f1_p10"],
                "recall_deep_large": agg["recall_deep_large"],
                "slide_recall": agg["slides"],
                "false_alarm_m2_per_km2_median": fa["median"],
                "false_alarm_m2_per_km2_worst": fa["worst"],
            }
        out["methods"][method] = rows
    return out


def publish_benchmark(report: dict[str, Any], scorer_path: Path, command: str) -> None:
    """Write the benchmark's figures into the scorer's card (atomically)."""
    data = json.loads(Path(scorer_path).read_text())
    data["card"]["benchmark"] = {"command": command, **benchmark_figures(report)}
    write_text_atomic(Path(scorer_path), json.dumps(data, indent=1))
