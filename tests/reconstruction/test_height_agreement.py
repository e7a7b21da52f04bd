"""The survey's own estimate of its dense heights' noise (worker/pipeline/height_agreement.py):
the heights of pairs that share no frame, compared where both measured a cell."""

import numpy as np
import pytest

from worker.pipeline.height_agreement import pair_agreement


def _pairs(seed: int, sigma: tuple[float, ...], first_kf: tuple[int, ...], shared: float = 0.0):
    """Dense points of several pairs over the same 20 x 20 m of flat ground (cells of
    0.5 m), each pair's heights with its own noise; `shared`: an error per cell common
    to all pairs (as the errors of a frame both pairs use)."""
    rng = np.random.default_rng(seed)
    common = rng.normal(0, shared, (40, 40)) if shared else np.zeros((40, 40))
    points, kf, partner = [], [], []
    for s, k in zip(sigma, first_kf, strict=True):
        x, y = rng.uniform(0, 20, (2, 40_000))
        cells = (np.floor(x / 0.5).astype(int), np.floor(y / 0.5).astype(int))
        z = 100.0 + common[cells] + rng.normal(0, s, x.size)
        points.append(np.column_stack([x, y, z]))
        kf.append(np.full(x.size, k))
        partner.append(np.full(x.size, k + 1))
    return np.concatenate(points), np.concatenate(kf), np.concatenate(partner)


@pytest.mark.parametrize("sigma", [0.05, 0.3])
def test_the_noise_of_independent_pairs_is_recovered(sigma):
    # Cells of 0.5 m hold about 25 points of each pair: each pair's mean there has
    # sigma / 5 of noise (0.05 m: 1 cm; 0.3 m: 6 cm).
    points, kf, partner = _pairs(1, (sigma, sigma), (0, 5))
    found = pair_agreement(points, kf, partner, 0.5)
    per_cell = sigma / np.sqrt(40_000 / 1600)
    assert found["agreement_m"] == pytest.approx(per_cell, rel=0.1)
    assert found["cells"] > 1500


def test_neighbouring_pairs_are_not_compared_and_shared_errors_do_not_show():
    points, kf, partner = _pairs(2, (0.1, 0.1), (0, 1))
    assert pair_agreement(points, kf, partner, 0.5) is None
    # Errors common to both pairs cancel in their difference: a lower bound, as documented.
    points, kf, partner = _pairs(3, (0.02, 0.02), (0, 5), shared=0.5)
    assert pair_agreement(points, kf, partner, 0.5)["agreement_m"] < 0.02


def test_memory_stays_bounded_by_sampling():
    points, kf, partner = _pairs(4, (0.3, 0.3), (0, 5))
    full = pair_agreement(points, kf, partner, 0.5)
    sampled = pair_agreement(points, kf, partner, 0.5, max_points=40_000)
    # A seeded draw of each point with the same chance: about 40 000 of the 80 000.
    assert sampled["points_used"] == pytest.approx(40_000, abs=600)
    # Half the points per cell: the means' noise grows by the square root of 2.
    assert sampled["agreement_m"] == pytest.approx(full["agreement_m"] * np.sqrt(2), rel=0.15)
