"""The paper's training protocol (Table 3) for PatchNet: `train_patchnet`.

PyTorch, Adam, binary cross-entropy, batch 32, He initialisation and zero biases, random
flips, 20 % validation, learning rate 1e-6 (fixed) / 1e-5 (loose) held constant, L2
regularisation 0.01 (Adam's weight decay, i.e. 0.01 x w added to the gradient), 100
epochs. The patches are the paper's (worker/pipeline/cnn/patches.py), classes balanced
and optionally capped per class (the paper had 1561). Fixed training feeds the 32-pixel
centres; loose training crops the pre patch at random inside the margin and adds a
random vertical offset (augment.py). Validation uses the centre crop. The weights of the
last epoch are kept (the paper names no early stopping); the history records every epoch.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.cnn.models import PatchNet
from worker.pipeline.cnn.normalize import CLIP_UNITS, relative_patch_pair
from worker.pipeline.cnn.patches import PatchSet, balance_classes, extract_patches
from worker.pipeline.cnn.registry import ModelCard, save_model
from worker.training import augment
from worker.training.dataset import DatasetManifest, Pair
from worker.training.training import (
    CHECKPOINT,
    METRICS,
    Exclusion,
    LogFn,
    TrainingResult,
    binary_metrics,
    load_checkpoint,
    load_training_pairs,
    quiet,
    save_checkpoint,
    set_determinism,
    split_validation,
)

PAPER_LR = {"fixed": 1e-6, "loose": 1e-5}


def patch_dataset(pairs: list[Pair], seed: int = 0, max_per_class: int | None = None) -> PatchSet:
    """All usable patches of the pairs, classes balanced (seeded), optionally capped."""
    sets = [extract_patches(p.pre, p.post, p.mask, p.pixel_size_m, group=p.id) for p in pairs]
    patches = PatchSet.concat(sets)
    keep = balance_classes(patches.labels, seed=seed)
    if max_per_class is not None:
        rng = np.random.default_rng([seed, 1])
        pos = keep[patches.labels[keep] == 1]
        neg = keep[patches.labels[keep] == 0]
        if pos.size > max_per_class:
            pos = np.sort(rng.choice(pos, max_per_class, replace=False))
            neg = np.sort(rng.choice(neg, max_per_class, replace=False))
        keep = np.sort(np.concatenate([pos, neg]))
    return patches.subset(keep)


@dataclass
class PatchTrainingOptions:
    mode: str = "loose"  # "fixed" or "loose"
    epochs: int = 100
    batch_size: int = 32
    learning_rate: float | None = None  # None: the paper's, 1e-6 fixed / 1e-5 loose
    weight_decay: float = 0.01
    validation_fraction: float = 0.2
    max_per_class: int | None = None
    seed: int = 0
    num_threads: int = 2
    filters: tuple[int, ...] = (16, 32, 48, 48, 16)
    fc: tuple[int, ...] = (64, 64)

    def lr(self) -> float:
        if self.mode not in PAPER_LR:
            raise ValueError(f"mode must be 'fixed' or 'loose', not {self.mode!r}")
        return self.learning_rate if self.learning_rate is not None else PAPER_LR[self.mode]


def _patch_batch(
    data: PatchSet, index: np.ndarray, mode: str, rng: np.random.Generator | None
) -> tuple[torch.Tensor, torch.Tensor]:
    pre, post = data.pre[index], data.post[index]
    size = data.pixel_size_m[index][:, None, None]
    if rng is None or mode == "fixed":
        pre32, post32 = augment.fixed_crop(pre, post)
    else:
        pre32, post32, _, _ = augment.loose_crop(pre, post, data.pixel_size_m[index], rng)
    a, b = relative_patch_pair(pre32, post32, size)
    if rng is not None:
        (a, b), _ = augment.random_flips(rng, a, b)
    x = torch.from_numpy(np.ascontiguousarray(np.stack([a, b], axis=1)))
    y = torch.from_numpy(data.labels[index].astype(np.float32))
    return x, y


@torch.no_grad()
def _evaluate_patches(model: PatchNet, data: PatchSet, batch: int = 256) -> dict[str, float]:
    model.eval()
    losses, probs = [], []
    loss_fn = nn.BCEWithLogitsLoss(reduction="sum")
    for start in range(0, len(data), batch):
        index = np.arange(start, min(start + batch, len(data)))
        x, y = _patch_batch(data, index, "fixed", None)
        logits = model(x)
        losses.append(float(loss_fn(logits, y)))
        probs.append(torch.sigmoid(logits).numpy())
    p = np.concatenate(probs) if probs else np.zeros(0)
    metrics = binary_metrics(data.labels == 1, p >= 0.5)
    metrics["loss"] = sum(losses) / max(len(data), 1)
    return metrics


def train_patchnet(
    manifest: DatasetManifest,
    out_dir: Path,
    name: str,
    options: PatchTrainingOptions | None = None,
    exclude: Exclusion | None = None,
    log: LogFn = quiet,
) -> TrainingResult:
    """Train the paper's PatchNet by Table 3; writes the model, card and metrics."""
    options = options or PatchTrainingOptions()
    lr = options.lr()
    start_time = time.perf_counter()
    set_determinism(options.seed, options.num_threads)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pairs = load_training_pairs(manifest, exclude)
    data = patch_dataset(pairs, options.seed, options.max_per_class)
    del pairs
    train_idx, val_idx = split_validation(len(data), options.validation_fraction, options.seed)
    train, val = data.subset(train_idx), data.subset(val_idx)
    log(f"{name}: {len(train)} training / {len(val)} validation patches, mode {options.mode}")

    model = PatchNet(options.filters, options.fc)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=options.weight_decay)
    loss_fn = nn.BCEWithLogitsLoss()
    history: list[dict[str, Any]] = []
    first_epoch = 0
    checkpoint = load_checkpoint(out / CHECKPOINT)
    if checkpoint is not None and checkpoint.get("name") == name:
        model.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        history = json.loads(checkpoint["history"])
        first_epoch = int(checkpoint["epoch"])
        log(f"{name}: resumed after epoch {first_epoch}")

    for epoch in range(first_epoch, options.epochs):
        model.train()
        rng = np.random.default_rng([options.seed, 100 + epoch])
        order = rng.permutation(len(train))
        total, seen = 0.0, 0
        t0 = time.perf_counter()
        for start in range(0, len(order), options.batch_size):
            index = order[start : start + options.batch_size]
            if index.size < 2:  # batch norm needs two samples
                continue
            x, y = _patch_batch(train, index, options.mode, rng)
            optimizer.zero_grad()
            loss = loss_fn(model(x), y)
            loss.backward()
            optimizer.step()
            total += loss.item() * index.size
            seen += index.size
        val_metrics = _evaluate_patches(model, val)
        record = {
            "epoch": epoch + 1,
            "train_loss": total / max(seen, 1),
            "val_loss": val_metrics["loss"],
            "val_accuracy": val_metrics["accuracy"],
            "val_f1": val_metrics["f1"],
            "seconds": time.perf_counter() - t0,
        }
        history.append(record)
        log(
            f"{name} epoch {epoch + 1}/{options.epochs}: loss {record['train_loss']:.4f} "
            f"val loss {record['val_loss']:.4f} acc {record['val_accuracy']:.3f} "
            f"f1 {record['val_f1']:.3f} ({record['seconds']:.1f} s)"
        )
        save_checkpoint(
            out / CHECKPOINT,
            {
                "name": name,
                "epoch": epoch + 1,
                "model": model.state_dict(),
                "optimizer": optimizer.state_dict(),
                "history": json.dumps(history),
            },
        )
        write_text_atomic(out / METRICS, json.dumps({"name": name, "history": history}, indent=1))

    final = _evaluate_patches(model, val)
    card = ModelCard(
        name=name,
        version=datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ"),
        kind="patchnet",
        config=model.config,
        description=(
            f"The paper's patch classifier ({options.mode} training, Table 3 protocol); "
            "filter counts chosen by slidewatch (the paper's figure lost them)."
        ),
        normalization={
            "input": "2 x 32 x 32: pre, post",
            "units": "pixel sizes, relative to the mean of the pre patch (both channels)",
            "clip_units": CLIP_UNITS,
        },
        decision={"patch_threshold": 0.5},
        training={
            "protocol": f"paper Table 3, {options.mode}",
            **{k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(options).items()},
            "learning_rate": lr,
            "training_patches": len(train),
            "validation_patches": len(val),
            "exclude": asdict(exclude) if exclude else None,
            "epochs_run": len(history),
        },
        data=manifest.summary(),
        metrics={"validation": final},
        interim=manifest.interim,
        created_at=datetime.now(UTC).isoformat(timespec="seconds"),
    )
    card_path = save_model(model, card, out)
    write_text_atomic(
        out / METRICS, json.dumps({"name": name, "history": history, "final": final}, indent=1)
    )
    return TrainingResult(card_path, card, history, time.perf_counter() - start_time, first_epoch)


__all__ = ["PAPER_LR", "PatchTrainingOptions", "patch_dataset", "train_patchnet"]
