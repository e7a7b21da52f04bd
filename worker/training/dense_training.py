"""Our training protocol for SlideNet (dense output): `train_slidenet`.

Dense per-pixel BCE on random 128 x 128 tiles from pairs drawn uniformly (half of the
tiles centred on a landslide pixel, when the pair has any), Adam with cosine-decayed
learning rate, random flips and 90-degree rotations, zoom (tiles resampled from windows
0.4-2 times their size, the pixel size scaled alike, so slides of many sizes in pixels
are seen), and registration jitter (post resampled at a random horizontal offset of up
to `max_shift_px` pixels and raised by up to `max_offset_px` pixel sizes): the residual
error left after co-registration; and clean pairs: a share `clean_fraction` of the
tiles comes from the clean (truth) DSMs plus white noise of 0.05-1 pixel sizes, so the
model also serves DSMs far less noisy than the reconstruction's (SfM, lidar).

Validation: every pair is cut into 256-pixel blocks; a seeded 20 % of the blocks are
validation, never in the loss; it runs the test-time pyramid of inference (`scales`) on
the noisy (reconstruction-like) DSMs. After training, the pixel threshold that maximises
the patch F1 on the validation blocks is chosen and written into the model card.
Exclusion of the test region, determinism and resuming: training.py.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch import nn

from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.cnn.inference import crop_padded, patch_scores_from_probability, predict_dense
from worker.pipeline.cnn.models import SlideNet
from worker.pipeline.cnn.normalize import (
    CLIP_UNITS,
    DENSE_CHANNELS,
    DENSE_SCALE,
    REFERENCE_WINDOW_PX,
    dense_inputs,
    local_mean,
)
from worker.pipeline.cnn.patches import (
    PATCH_PX,
    centre_fractions,
    label_from_fraction,
    patch_origins,
    usable_windows,
    window_sums,
)
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
)


@dataclass
class DenseTrainingOptions:
    epochs: int = 50
    steps_per_epoch: int = 60
    batch_size: int = 8
    tile_px: int = 128
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    positive_fraction: float = 0.5  # share of tiles centred on a landslide pixel
    max_shift_px: float = 3.0
    max_offset_px: float = 2.0  # vertical, in pixel sizes
    block_px: int = 256
    validation_fraction: float = 0.2
    validate_every: int = 5
    seed: int = 0
    num_threads: int = 2
    widths: tuple[int, ...] = (16, 32, 64)
    thresholds: tuple[float, ...] = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9)
    zoom: tuple[float, float] = (0.5, 2.5)  # log-uniform tile zoom
    clean_fraction: float = 0.3  # share of tiles from clean (truth) DSMs + white noise
    clean_noise_px: tuple[float, float] = (0.05, 1.0)  # its std, in pixel sizes
    scales: tuple[int, ...] = (1, 2, 4)  # test-time pyramid, used for validation too


@dataclass
class _DensePair:
    pair: Pair
    train_pixels: np.ndarray  # bool: pixel in a training block
    positives: np.ndarray  # (K, 2) row, col of landslide pixels in training blocks
    anywhere: np.ndarray  # (M, 2) valid pixels in training blocks (subsampled)


def _blocks(shape: tuple[int, int], block: int, fraction: float, seed: int, key: int):
    nr, nc = math.ceil(shape[0] / block), math.ceil(shape[1] / block)
    rng = np.random.default_rng([seed, 3, key])
    val = rng.random((nr, nc)) < fraction
    full = np.repeat(np.repeat(val, block, axis=0), block, axis=1)[: shape[0], : shape[1]]
    return ~full


def _prepare_dense(pairs: list[Pair], options: DenseTrainingOptions) -> list[_DensePair]:
    prepared = []
    for key, pair in enumerate(pairs):
        train_pixels = _blocks(
            pair.pre.shape, options.block_px, options.validation_fraction, options.seed, key
        )
        valid = np.isfinite(pair.pre) & np.isfinite(pair.post) & (pair.mask != 255)
        pos = np.argwhere((pair.mask == 1) & valid & train_pixels)
        anywhere = np.argwhere(valid[::4, ::4] & train_pixels[::4, ::4]) * 4
        prepared.append(_DensePair(pair, train_pixels, pos, anywhere))
    return prepared


def _crop_mask(array: np.ndarray, r0: int, c0: int, size: int, fill: int) -> np.ndarray:
    out = np.full((size, size), fill, dtype=array.dtype)
    rs, cs = max(r0, 0), max(c0, 0)
    re, ce = min(r0 + size, array.shape[0]), min(c0 + size, array.shape[1])
    if re > rs and ce > cs:
        out[rs - r0 : re - r0, cs - c0 : ce - c0] = array[rs:re, cs:ce]
    return out


def _resize_elevation(array: np.ndarray, size: int) -> np.ndarray:
    """Resample a square window to size x size; a pixel touching nodata is nodata."""
    valid = np.isfinite(array)
    shrink = size < array.shape[0]
    mode = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    filled = np.where(valid, array, 0.0).astype(np.float32)
    out = cv2.resize(filled, (size, size), interpolation=mode).astype(np.float64)
    weight = cv2.resize(valid.astype(np.float32), (size, size), interpolation=mode)
    out[weight < 0.999] = np.nan
    return out


def _dense_sample(
    item: _DensePair, rng: np.random.Generator, options: DenseTrainingOptions, positive: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One training tile: (4, t, t) inputs, (t, t) labels, (t, t) loss weights.

    Zoom: the tile is cut from a source window `zoom` times smaller (zoom > 1: the slide
    looks bigger and deeper in pixel units) and resampled, with the pixel size divided by
    `zoom`, so the model sees slides of many sizes in pixels.
    """
    pair = item.pair
    t = options.tile_px
    halo = REFERENCE_WINDOW_PX // 2 + math.ceil(options.max_shift_px) + 1
    size = t + 2 * halo
    lo, hi = options.zoom
    zoom = float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) if hi > lo else float(lo)
    src = max(8, round(size / zoom))
    source = item.positives if positive and len(item.positives) else item.anywhere
    r, c = source[rng.integers(len(source))]
    r0 = int(r) - src // 2 + int(rng.integers(-src // 6, src // 6 + 1))
    c0 = int(c) - src // 2 + int(rng.integers(-src // 6, src // 6 + 1))
    clean = (
        pair.truth_pre is not None
        and pair.truth_post is not None
        and rng.random() < options.clean_fraction
    )
    if clean:
        sigma = float(rng.uniform(*options.clean_noise_px)) * pair.pixel_size_m
        pre_w = crop_padded(pair.truth_pre, r0, c0, src, src)
        post_w = crop_padded(pair.truth_post, r0, c0, src, src)
        pre_w = pre_w + rng.normal(0.0, sigma, pre_w.shape).astype(np.float32)
        post_w = post_w + rng.normal(0.0, sigma, post_w.shape).astype(np.float32)
    else:
        pre_w = crop_padded(pair.pre, r0, c0, src, src)
        post_w = crop_padded(pair.post, r0, c0, src, src)
    mask_w = _crop_mask(pair.mask, r0, c0, src, 255)
    train_w = _crop_mask(item.train_pixels, r0, c0, src, False)
    pixel_size = pair.pixel_size_m
    if src != size:
        pre_w, post_w = _resize_elevation(pre_w, size), _resize_elevation(post_w, size)
        mask_w = cv2.resize(mask_w, (size, size), interpolation=cv2.INTER_NEAREST)
        train_w = cv2.resize(
            train_w.astype(np.uint8), (size, size), interpolation=cv2.INTER_NEAREST
        ).astype(bool)
        pixel_size = pair.pixel_size_m * src / size
    core = (slice(halo, halo + t), slice(halo, halo + t))
    reference = local_mean(pre_w)[core]
    shift = tuple(rng.uniform(-options.max_shift_px, options.max_shift_px, 2))
    offset = float(rng.uniform(-options.max_offset_px, options.max_offset_px)) * pixel_size
    post_t = augment.registration_jitter(post_w, (t, t), halo, shift, offset)
    x = dense_inputs(pre_w[core], post_t, pixel_size, reference)
    mask = mask_w[core]
    y = (mask == 1).astype(np.float32)
    w = ((mask != 255) & train_w[core] & (x[3] > 0)).astype(np.float32)
    k = int(rng.integers(4))
    flip = bool(rng.integers(2))
    arrays = []
    for a in (x, y[None], w[None]):
        a = np.rot90(a, k, axes=(-2, -1))
        if flip:
            a = a[..., ::-1]
        arrays.append(np.ascontiguousarray(a))
    return arrays[0], arrays[1][0], arrays[2][0]


def _validate_dense(
    model: SlideNet,
    items: list[_DensePair],
    thresholds: tuple[float, ...],
    num_threads: int,
    scales: tuple[int, ...] = (1,),
) -> dict[str, Any]:
    """Pixel loss and patch P/R/F1 (paper grid, 10 % rule) on the validation blocks."""
    per_threshold = {t: [] for t in thresholds}
    truths = []
    loss_sum, loss_n = 0.0, 0
    for item in items:
        pair = item.pair
        prob = predict_dense(
            model, pair.pre, pair.post, pair.pixel_size_m, num_threads=num_threads, scales=scales
        )
        val_pixels = ~item.train_pixels & (pair.mask != 255)
        valid = val_pixels & np.isfinite(pair.pre) & np.isfinite(pair.post)
        p = np.clip(prob[valid].astype(np.float64), 1e-6, 1 - 1e-6)
        y = pair.mask[valid] == 1
        loss_sum += float(-(y * np.log(p) + (~y) * np.log(1 - p)).sum())
        loss_n += int(valid.sum())
        rows, cols = patch_origins(pair.pre.shape)
        truth = label_from_fraction(centre_fractions(pair.mask, rows, cols))
        usable = usable_windows(pair.pre, pair.post, rows, cols, pair.mask)
        # Patches wholly in validation blocks.
        in_val = _window_all(~item.train_pixels, rows, cols) & usable
        truths.append(truth[in_val])
        for t in thresholds:
            _, predicted = patch_scores_from_probability(prob, rows, cols, t)
            per_threshold[t].append(predicted[in_val])
    truth_all = np.concatenate(truths) if truths else np.zeros(0, bool)
    results = {}
    for t in thresholds:
        results[str(t)] = binary_metrics(truth_all == 1, np.concatenate(per_threshold[t]) == 1)
    best = max(thresholds, key=lambda t: (results[str(t)]["f1"], -abs(t - 0.5)))
    return {
        "pixel_loss": loss_sum / max(loss_n, 1),
        "patches": int(truth_all.size),
        "positive_patches": int((truth_all == 1).sum()),
        "by_threshold": results,
        "best_threshold": best,
        "best_f1": results[str(best)]["f1"],
    }


def _window_all(flag: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    return window_sums((~flag).astype(np.float64), rows, cols, PATCH_PX) == 0


def train_slidenet(
    manifest: DatasetManifest,
    out_dir: Path,
    name: str,
    options: DenseTrainingOptions | None = None,
    exclude: Exclusion | None = None,
    log: LogFn = quiet,
    pairs: list[Pair] | None = None,
) -> TrainingResult:
    """Train SlideNet (see the module doc); writes the model, card and metrics."""
    options = options or DenseTrainingOptions()
    start_time = time.perf_counter()
    set_determinism(options.seed, options.num_threads)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if pairs is None:
        pairs = load_training_pairs(manifest, exclude, truth=options.clean_fraction > 0)
    items = _prepare_dense(pairs, options)
    model = SlideNet(options.widths)
    optimizer = torch.optim.Adam(
        model.parameters(), lr=options.learning_rate, weight_decay=options.weight_decay
    )
    total_steps = options.epochs * options.steps_per_epoch
    scheduler = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: 0.5 * (1 + math.cos(math.pi * min(step, total_steps) / total_steps))
    )
    history: list[dict[str, Any]] = []
    first_epoch = 0
    checkpoint = load_checkpoint(out / CHECKPOINT)
    if checkpoint is not None and checkpoint.get("name") == name:
        model.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        scheduler.load_state_dict(checkpoint["scheduler"])
        history = json.loads(checkpoint["history"])
        first_epoch = int(checkpoint["epoch"])
        log(f"{name}: resumed after epoch {first_epoch}")
    log(f"{name}: {len(items)} pairs, {options.epochs} epochs x {options.steps_per_epoch} steps")

    validation: dict[str, Any] = {}
    for epoch in range(first_epoch, options.epochs):
        model.train()
        rng = np.random.default_rng([options.seed, 200 + epoch])
        t0 = time.perf_counter()
        total = 0.0
        for _ in range(options.steps_per_epoch):
            xs, ys, ws = [], [], []
            for _ in range(options.batch_size):
                item = items[int(rng.integers(len(items)))]
                positive = rng.random() < options.positive_fraction
                x, y, w = _dense_sample(item, rng, options, positive)
                xs.append(x)
                ys.append(y)
                ws.append(w)
            x = torch.from_numpy(np.stack(xs))
            y = torch.from_numpy(np.stack(ys))
            w = torch.from_numpy(np.stack(ws))
            logits = model(x)
            loss = nn.functional.binary_cross_entropy_with_logits(
                logits, y, weight=w, reduction="sum"
            ) / w.sum().clamp(min=1.0)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            scheduler.step()
            total += loss.item()
        record: dict[str, Any] = {
            "epoch": epoch + 1,
            "train_loss": total / options.steps_per_epoch,
            "learning_rate": scheduler.get_last_lr()[0],
            "seconds": time.perf_counter() - t0,
        }
        if (epoch + 1) % options.validate_every == 0 or epoch + 1 == options.epochs:
            model.eval()
            validation = _validate_dense(
                model, items, options.thresholds, options.num_threads, options.scales
            )
            record["val_pixel_loss"] = validation["pixel_loss"]
            record["val_best_f1"] = validation["best_f1"]
            record["val_best_threshold"] = validation["best_threshold"]
        history.append(record)
        log(
            f"{name} epoch {epoch + 1}/{options.epochs}: loss {record['train_loss']:.4f}"
            + (
                f" val loss {record['val_pixel_loss']:.4f} patch F1 {record['val_best_f1']:.3f}"
                f" @ {record['val_best_threshold']}"
                if "val_best_f1" in record
                else ""
            )
            + f" ({record['seconds']:.1f} s)"
        )
        save_checkpoint(
            out / CHECKPOINT,
            {
                "name": name,
                "epoch": epoch + 1,
                "model": model.state_dict(),
                "optimizer": optimizer.state_dict(),
                "scheduler": scheduler.state_dict(),
                "history": json.dumps(history),
            },
        )
        write_text_atomic(out / METRICS, json.dumps({"name": name, "history": history}, indent=1))

    if not validation:
        model.eval()
        validation = _validate_dense(
            model, items, options.thresholds, options.num_threads, options.scales
        )
    model.eval()
    card = ModelCard(
        name=name,
        version=datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ"),
        kind="slidenet",
        config=model.config,
        description=(
            "slidewatch's dense landslide detector: co-registered pre/post DSMs in, "
            "per-pixel landslide probability out; cells by the paper's 10 % rule."
        ),
        normalization={
            "channels": list(DENSE_CHANNELS),
            "units": "pixel sizes, relative to the 33-pixel local mean of pre",
            "scale": DENSE_SCALE,
            "clip_units": CLIP_UNITS,
            "reference_window_px": REFERENCE_WINDOW_PX,
        },
        decision={
            "pixel_threshold": float(validation["best_threshold"]),
            "scales": list(options.scales),
            "cell_rule": "landslide pixels > 10 % of a 32-pixel cell",
        },
        training={
            "protocol": "slidewatch dense (training.py)",
            **{k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(options).items()},
            "exclude": asdict(exclude) if exclude else None,
            "epochs_run": len(history),
        },
        data=manifest.summary(),
        metrics={"validation": validation},
        interim=manifest.interim,
        created_at=datetime.now(UTC).isoformat(timespec="seconds"),
    )
    card_path = save_model(model, card, out)
    write_text_atomic(
        out / METRICS,
        json.dumps({"name": name, "history": history, "final": validation}, indent=1),
    )
    return TrainingResult(card_path, card, history, time.perf_counter() - start_time, first_epoch)


__all__ = ["DenseTrainingOptions", "train_slidenet"]
