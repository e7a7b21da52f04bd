"""Training: what both protocols share (paper_training.py, dense_training.py).

The pair and region that form the test set (`Exclusion`) are blanked to nodata in the
training copy of that pair (with a margin), so no test pixel is seen, even as context.
Deterministic on CPU: seeded numpy generators per epoch, torch.manual_seed,
torch.use_deterministic_algorithms(True), a fixed thread count. After every epoch a
checkpoint (model, optimiser, history) is written atomically; a run started again with
the same output folder and model name resumes from it.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy import ndimage

from worker.pipeline.atomic import atomic_path
from worker.pipeline.cnn.patches import PATCH_PX
from worker.pipeline.cnn.registry import ModelCard
from worker.training.dataset import DatasetManifest, Pair, load_pair

LogFn = Callable[[str], None]
CHECKPOINT = "checkpoint.pt"
METRICS = "metrics.json"


def quiet(_message: str) -> None:
    pass


def set_determinism(seed: int, num_threads: int) -> None:
    torch.manual_seed(seed)
    torch.set_num_threads(num_threads)
    torch.use_deterministic_algorithms(True)


# ------------------------------------------------------------------------------------
# Data


@dataclass(frozen=True)
class Exclusion:
    """Blank `region` of pair `pair` (both DSMs) from training, grown by `margin_px`."""

    pair: str
    region: str
    margin_px: int = PATCH_PX


def load_training_pairs(
    manifest: DatasetManifest,
    exclude: Exclusion | None = None,
    pair_ids: list[str] | None = None,
    truth: bool = False,
) -> list[Pair]:
    """The manifest's pairs, with the excluded region set to nodata in its pair."""
    import rasterio

    pairs = []
    for spec in manifest.pairs:
        if pair_ids is not None and spec.id not in pair_ids:
            continue
        pair = load_pair(spec, truth=truth)
        if exclude is not None and spec.id == exclude.pair:
            with rasterio.open(manifest.regions[exclude.region]) as src:
                region = src.read(1) == 1
            if region.shape != pair.pre.shape:
                raise ValueError("the excluded region is not on the pair's grid")
            grown = ndimage.binary_dilation(region, iterations=exclude.margin_px)
            pair.pre = pair.pre.copy()
            pair.post = pair.post.copy()
            pair.pre[grown] = np.nan
            pair.post[grown] = np.nan
            for name in ("truth_pre", "truth_post"):
                clean = getattr(pair, name)
                if clean is not None:
                    clean = clean.copy()
                    clean[grown] = np.nan
                    setattr(pair, name, clean)
            pair.mask = pair.mask.copy()
            pair.mask[grown] = 255
        pairs.append(pair)
    return pairs


def split_validation(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded random split of range(n): (train indices, validation indices), sorted."""
    order = np.random.default_rng([seed, 2]).permutation(n)
    n_val = round(n * fraction)
    return np.sort(order[n_val:]), np.sort(order[:n_val])


def binary_metrics(truth: np.ndarray, predicted: np.ndarray) -> dict[str, float]:
    truth = np.asarray(truth).astype(bool)
    predicted = np.asarray(predicted).astype(bool)
    tp = int(np.count_nonzero(truth & predicted))
    fp = int(np.count_nonzero(~truth & predicted))
    fn = int(np.count_nonzero(truth & ~predicted))
    tn = int(np.count_nonzero(~truth & ~predicted))
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / (tp + fn) if tp + fn else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "tn": tn,
        "precision": precision,
        "recall": recall,
        "f1": f1,
        "accuracy": (tp + tn) / max(tp + fp + fn + tn, 1),
    }


# ------------------------------------------------------------------------------------
# Checkpoints


def save_checkpoint(path: Path, payload: dict[str, Any]) -> None:
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buffer.getvalue())


def load_checkpoint(path: Path) -> dict[str, Any] | None:
    if not path.exists():
        return None
    return torch.load(path, map_location="cpu", weights_only=True)


@dataclass
class TrainingResult:
    card_path: Path
    card: ModelCard
    history: list[dict[str, Any]]
    seconds: float
    resumed_from_epoch: int


__all__ = [
    "CHECKPOINT",
    "METRICS",
    "Exclusion",
    "LogFn",
    "TrainingResult",
    "binary_metrics",
    "load_checkpoint",
    "load_training_pairs",
    "quiet",
    "save_checkpoint",
    "set_determinism",
    "split_validation",
]
