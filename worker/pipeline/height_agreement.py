"""How well the dense heights agree where independent image pairs measured the same
ground: the survey's own estimate of its DSM's noise, without any truth.

Each dense point comes from one keyframe pair. In a DSM cell seen by two pairs that
share no frame (keyframes at least `min_gap` apart: the earliest and the latest pair in
the cell), the difference of their mean heights has twice the variance of one pair's;
the NMAD of those differences over all such cells, over the square root of 2, is the
height noise of one pair. Neighbouring pairs share a frame and its errors, so they are
not compared (their spread was 2-4 times smaller than the error against the truth).

Measured on the many-flight benchmark (seeds 13-36, 320 x 180 video; 2026-11-27) against
the simulator's truth: over the mounds the figure is within 0.7-1.5 times the DSM's NMAD
(2.5-5.8 cells where the NMAD is 2.4-5.0); over the forested hillslope it is about half
of it (4.5-10 cells where the NMAD is 7.7-41), still above the check's bound every time.
It is a lower bound of the error, never a proof of accuracy: errors common to every pair
(a wrong focal length, the canopy's occlusions) do not show in it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from worker.pipeline.binned import run_starts


def pair_agreement(
    points: np.ndarray,
    kf: np.ndarray,
    partner: np.ndarray,
    cell_m: float,
    min_gap: int = 2,
    max_points: int = 2_000_000,
) -> dict[str, Any] | None:
    """The height noise of one pair (metres, 1 sigma) from cells seen by two pairs whose
    first keyframes are `min_gap` or more apart; None when fewer than 100 such cells.
    At most `max_points` points (drawn at random, seeded) are used, so memory stays
    bounded on any survey."""
    n = len(points)
    if n == 0:
        return None
    if n > max_points:
        # A seeded Bernoulli draw: a tenth of the cost of choosing without replacement.
        pick = np.flatnonzero(np.random.default_rng(0).random(n) < max_points / n)
        points, kf, partner = points[pick], kf[pick], partner[pick]
    x = np.floor(points[:, 0] / cell_m).astype(np.int64)
    y = np.floor(points[:, 1] / cell_m).astype(np.int64)
    x -= x.min()
    y -= y.min()
    cell = x * (int(y.max()) + 1) + y
    # A pair as one integer ordered by its first keyframe (np.unique over rows, axis=0,
    # took 3 of the DSM stage's 11 s on a 30-s flight).
    partners = int(partner.max()) + 1
    pair_codes, pair = np.unique(kf.astype(np.int64) * partners + partner, return_inverse=True)
    n_pairs = len(pair_codes)
    key = cell * n_pairs + pair.ravel()
    order = np.argsort(key)
    key = key[order]
    new_key = run_starts(key)
    group = np.cumsum(new_key) - 1
    mean = np.bincount(group, weights=points[order, 2]) / np.bincount(group)
    keys = key[new_key]
    key_cell = keys // n_pairs
    first_kf = pair_codes[keys % n_pairs] // partners
    # Keys sort by cell, then by pair (by its first keyframe): a cell's first and last
    # keys are its earliest and latest pairs.
    first = np.flatnonzero(run_starts(key_cell))
    last = np.append(first[1:], keys.size) - 1
    apart = np.abs(first_kf[last] - first_kf[first]) >= min_gap
    if apart.sum() < 100:
        return None
    diff = mean[first[apart]] - mean[last[apart]]
    nmad = 1.4826 * float(np.median(np.abs(diff - np.median(diff))))
    return {
        "agreement_m": round(nmad / np.sqrt(2.0), 4),
        "cells": int(apart.sum()),
        "points_used": len(points),
    }
