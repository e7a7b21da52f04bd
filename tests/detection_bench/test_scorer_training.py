"""The scorer's training: logistic fit, Platt calibration, the recall-first threshold,
and a scorer that round-trips through its JSON."""

import numpy as np
import pytest

from worker.detection_bench.scorer_training import (
    TRAITS,
    Candidates,
    fit_logistic,
    fit_platt,
    recall_first_threshold,
    reliability,
    save_scorer,
    train_scorer,
)
from worker.pipeline.scorer import load_scorer


def _candidates(rng: np.random.Generator, n: int, generator: str, shift: float) -> Candidates:
    """Landslides have a larger mean_lod_ratio and edge contrast; the rest is noise."""
    labels = (rng.random(n) < 0.3).astype(int)
    traits = []
    for y in labels:
        t = {name: float(rng.normal()) for name in TRAITS}
        t["mean_lod_ratio"] += 2.5 * y + shift
        t["edge_contrast"] += 1.5 * y
        traits.append(t)
    # One pair per candidate; a landslide candidate covers its pair's one slide whole,
    # within the LoD mask too.
    pairs = [f"{generator}/{i}/pair" for i in range(n)]
    cover = [{"1": 100} if y else {} for y in labels]
    slides = {pair: {"1": 100} for pair, y in zip(pairs, labels, strict=True) if y}
    return Candidates(
        traits,
        labels,
        [generator] * n,
        pairs,
        cover,
        [dict(c) for c in cover],
        [False] * n,
        slides,
    )


def _merge(*parts: Candidates) -> Candidates:
    return Candidates(
        [t for p in parts for t in p.traits],
        np.concatenate([p.labels for p in parts]),
        [g for p in parts for g in p.generators],
        [x for p in parts for x in p.pairs],
        [x for p in parts for x in p.cover],
        [x for p in parts for x in p.lod_cover],
        [x for p in parts for x in p.surface],
        {k: v for p in parts for k, v in p.slides.items()},
    )


def test_logistic_fit_separates_and_platt_calibrates():
    rng = np.random.default_rng(0)
    data = _candidates(rng, 2000, "a", 0.0)
    mean, scale, coef, intercept = fit_logistic(data.matrix(), data.labels)
    logits = ((data.matrix() - mean) / scale) @ coef + intercept
    order = np.argsort(logits)
    # The landslides rank high: most of the top fifth are landslides.
    assert data.labels[order[-400:]].mean() > 0.9
    a, b = fit_platt(logits, data.labels)
    p = 1 / (1 + np.exp(-(a * logits + b)))
    assert reliability(p, data.labels)["ece"] < 0.05


def test_recall_first_threshold_keeps_the_target_share():
    rng = np.random.default_rng(1)
    p = rng.random(1000)
    y = (rng.random(1000) < p).astype(int)
    t = recall_first_threshold(p, y, 0.95)
    assert t <= 0.5
    assert (p[y == 1] >= t).mean() >= 0.95


def test_train_scorer_holds_generators_apart_and_round_trips(tmp_path):
    rng = np.random.default_rng(2)
    data = _merge(
        _candidates(rng, 800, "fit", 0.0),
        _candidates(rng, 800, "cal", 0.5),
        _candidates(rng, 800, "unseen", -0.5),
    )
    scorer = train_scorer(data, ["fit"], ["cal"], target_recall=0.98)
    card = scorer.card
    assert card["training_generators"] == ["fit"]
    assert card["calibration_generators"] == ["cal"]
    assert card["held_out_generators"] == ["unseen"]
    assert card["reliability_calibration"]["ece"] < 0.08
    cal = data.subset(["cal"])
    # Recall first: every calibration slide the LoD regions find is still found.
    assert card["calibration_slide_recall"] == {"lod": 1.0, "scored": 1.0}
    kept = scorer.probability(cal.traits)[cal.labels == 1] >= scorer.threshold
    assert kept.all() and 0 < scorer.threshold <= 0.5
    save_scorer(scorer, tmp_path / "scorer.json")
    again = load_scorer(tmp_path / "scorer.json")
    assert again.reference == scorer.reference and again.threshold == scorer.threshold
    np.testing.assert_allclose(again.probability(cal.traits), scorer.probability(cal.traits))


def test_a_split_without_landslides_is_refused():
    rng = np.random.default_rng(3)
    data = _candidates(rng, 100, "fit", 0.0)
    data.labels[:] = 0
    with pytest.raises(ValueError, match="landslide candidates"):
        train_scorer(data, ["fit"], ["fit"])


def test_leave_one_out_folds_never_contain_the_generator_scored():
    from worker.detection_bench.leave_one_out import folds

    names = ["a", "b", "c", "d", "e", "f"]
    plan = folds(names)
    assert set(plan) == set(names)
    for name, (training, calibration) in plan.items():
        assert name not in training and name not in calibration
        assert not set(training) & set(calibration)
        assert len(calibration) == 2 and len(training) == 3


def test_the_simulator_pairs_twin_differs_by_the_slide_alone():
    from worker.detection_bench.simulator_pairs import SimulatorPairs

    pair, twin = SimulatorPairs().make(4), SimulatorPairs().make(4, no_change=True)
    assert np.array_equal(pair.pre, twin.pre) and not twin.slides
    changed = pair.post - twin.post
    np.testing.assert_allclose(changed, pair.true_dh, atol=1e-5)
    slide = pair.slides[0]
    assert slide.area_px == int(np.count_nonzero(pair.slide_labels))
    assert slide.volume_loss_m3 == pytest.approx(slide.volume_gain_m3, rel=0.05)
