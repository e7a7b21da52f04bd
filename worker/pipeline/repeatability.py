"""Registration error between repeated surveys of one site, measured at checkpoints.

The paper (Table 1) flew one field three times, reconstructed and georeferenced each
flight without ground control, and reported the mean location difference of the three
models at three checkpoints, per axis. `mean_pairwise_difference` is that figure from
each survey's checkpoint positions.

Before two surveys are compared the platform co-registers the later DSM onto the earlier
one on stable terrain (align, then coregister). `coregister_checkpoints` moves a
survey's checkpoints by that correction, so the same figure can be given for what change
detection actually sees.
"""

from __future__ import annotations

import itertools
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from worker.pipeline.align import align
from worker.pipeline.coregister import CoregisterOptions, CoregisterResult, coregister
from worker.pipeline.errors import InputError


def mean_pairwise_difference(positions: Sequence[np.ndarray]) -> np.ndarray:
    """Mean |difference| per axis (east, north, up) over every pair of surveys and every
    checkpoint; positions[i] is survey i's (K, 3) checkpoint coordinates."""
    if len(positions) < 2:
        raise InputError("at least two surveys are needed to measure their difference")
    stacked = [np.asarray(p, dtype=np.float64) for p in positions]
    if len({p.shape for p in stacked}) != 1 or stacked[0].ndim != 2 or stacked[0].shape[1] != 3:
        raise InputError("every survey needs the same (K, 3) checkpoint coordinates")
    diffs = [np.abs(a - b) for a, b in itertools.combinations(stacked, 2)]
    return np.concatenate(diffs).mean(axis=0)


def coregister_checkpoints(
    reference_dsm: Path,
    survey_dsm: Path,
    checkpoints: np.ndarray,
    options: CoregisterOptions | None = None,
) -> tuple[np.ndarray, CoregisterResult]:
    """Checkpoints (K, 3) of the survey moved by the co-registration of its DSM onto the
    reference DSM (both resampled onto their common grid first, as the comparison does).
    The checkpoints must be in the CRS of the common grid: the reference DSM's when it
    is metric."""
    with tempfile.TemporaryDirectory(prefix="slidewatch-coreg-") as tmp:
        work = Path(tmp)
        align(reference_dsm, survey_dsm, work / "reference.tif", work / "survey.tif")
        result = coregister(
            work / "reference.tif", work / "survey.tif", work / "survey_on_reference.tif", options
        )
    return result.correct_points(checkpoints), result
