"""A reconstruction against its simulated truth: the DSM and the camera trajectory.

Shared by the single-survey benchmark (benchmarks/reconstruction.py) and the many-flight
one (benchmarks/flights.py), so that both measure the same way:

- `dsm_errors`: DSM minus truth DSM on the DSM's grid (NMAD, 95th percentile of
  |error - median|, median), over the measured cells and over all;
- `coregistered_error`: the same after co-registering the DSM onto the truth (shift and
  tilt, as the comparison co-registers two surveys), in metres and DSM pixels, over the
  same measured cells as the figure as georeferenced (the co-registration's own NMAD is
  over the cells it kept, within 2 m of the truth, and is kept as `nmad_inliers_m`);
- `trajectory_errors`: camera centres against the true trajectory, after the similarity
  that maps one onto the other (shape) and as georeferenced (absolute).
"""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import rasterio

from worker.pipeline.georef import Similarity, umeyama
from worker.pipeline.trajectory import read_trajectory_csv
from worker.training.reconstructed_data import register_to_truth


def read_truth_trajectory(path: Path) -> dict[str, np.ndarray]:
    """The simulator's trajectory.csv, one array per column (utc left out)."""
    with open(path, encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0] if k != "utc"}


def truth_at(truth: dict[str, np.ndarray], t: np.ndarray, keys: tuple[str, ...]) -> np.ndarray:
    """The truth's columns `keys` interpolated at video times `t`."""
    return np.column_stack([np.interp(t, truth["t_s"], truth[k]) for k in keys])


def robust(values: np.ndarray) -> dict[str, float]:
    """Median, NMAD and 95th percentile of |value - median| of the finite values."""
    values = values[np.isfinite(values)]
    if values.size == 0:
        return {}
    med = float(np.median(values))
    dev = np.abs(values - med)
    return {
        "median": round(med, 4),
        "nmad": round(1.4826 * float(np.median(dev)), 4),
        "p95": round(float(np.percentile(dev, 95)), 4),
        "cells": int(values.size),
    }


def dsm_errors(
    work: Path,
    truth_dsm: Path,
    to_truth: Similarity | Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict[str, Any]:
    """DSM minus truth on the DSM's grid; `to_truth` (a similarity, or a function of
    (N, 3) points) moves the DSM's cells onto the truth first."""
    with rasterio.open(work / "dsm.tif") as src:
        dsm = src.read(1, masked=True).filled(np.nan)
        transform = src.transform
    with rasterio.open(work / "dsm_filled.tif") as src:
        filled = src.read(1)
    rows, cols = np.indices(dsm.shape)
    x, y = transform * (cols + 0.5, rows + 0.5)
    pts = np.column_stack([x.ravel(), y.ravel(), dsm.ravel()])
    if isinstance(to_truth, Similarity):
        pts = to_truth.apply(pts)
    elif to_truth is not None:
        pts = to_truth(pts)
    with rasterio.open(truth_dsm) as src:
        truth = src.read(1, masked=True).filled(np.nan)
        c, r = ~src.transform * (pts[:, 0], pts[:, 1])
    finite = np.isfinite(pts).all(axis=1)
    c = np.floor(np.where(finite, c, -1)).astype(int)
    r = np.floor(np.where(finite, r, -1)).astype(int)
    ok = (c >= 0) & (c < truth.shape[1]) & (r >= 0) & (r < truth.shape[0]) & finite
    diff = np.full(pts.shape[0], np.nan)
    diff[ok] = pts[ok, 2] - truth[r[ok], c[ok]]
    diff = diff.reshape(dsm.shape)
    return {
        "measured": robust(diff[filled == 0]),
        "all": robust(diff[filled != 255]),
    }


def coregistered_error(run: Path, truth_dsm: Path, resolution_m: float) -> dict[str, Any]:
    """DSM error after co-registering the DSM onto the truth (shift and tilt, as the
    comparison co-registers two surveys): NMAD in metres and in DSM pixels."""
    reg = register_to_truth(run / "dsm.tif", truth_dsm, run / "dsm_on_truth.tif")
    # Every measured cell, as the figure as georeferenced counts them: the correction's
    # own NMAD leaves out cells more than 2 m off, which bounds it (4 px at 0.5 m).
    after = dsm_errors(run, truth_dsm, reg.correction.correct_points)["measured"]["nmad"]
    return {
        **reg.to_dict(),
        "nmad_inliers_m": round(reg.nmad_after_m, 4),
        "nmad_after_m": after,
        "nmad_px": round(after / float(resolution_m), 2),
    }


def trajectory_errors(work: Path, truth: dict[str, np.ndarray]) -> dict[str, Any]:
    """Camera centres of trajectory.csv against the truth: RMSE after the best
    similarity (the reconstruction's shape) and as georeferenced (absolute)."""
    traj = read_trajectory_csv(work / "trajectory.csv")
    true = truth_at(truth, traj.t, ("e", "n", "u"))
    sim = umeyama(traj.positions, true)
    shape = np.linalg.norm(sim.apply(traj.positions) - true, axis=1)
    absolute = traj.positions - true
    return {
        "frames": len(traj),
        "rmse_after_similarity_m": round(float(np.sqrt((shape**2).mean())), 4),
        "absolute_mean_enu_m": [round(float(v), 4) for v in absolute.mean(axis=0)],
        "absolute_rmse_m": round(float(np.sqrt((absolute**2).sum(axis=1).mean())), 4),
    }
