"""Inference: patch scores of the paper's model and dense probabilities of SlideNet.

Dense inference is tiled: the raster is cut into `tile_px` squares; each is read with a
halo of `HALO_PX` pixels at the coarsest scale (more than the model's receptive-field
radius plus the local reference window) so tiles join without seams. Tile origins are
multiples of 8 x the coarsest scale, so every tile sees the same down-sampling phase.

Test-time pyramid (`scales`, from the model card's decision rule unless overridden): the
model also runs on block means of 2 x 2 and 4 x 4 pixels (with the pixel size scaled
alike, so the inputs stay in pixel-size units); each probability is upsampled
bilinearly and the maximum is kept. Slides larger than the receptive field at full
resolution (a 300-pixel deep-seated slide at 20 cm) are then seen whole.

Outside the raster and where either DSM has no data the inputs are marked invalid, and
the probability there is set to 0: nodata is never a landslide.

The comparison's `detect` stage over files is in detect_stage.py.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from worker.pipeline.cnn.models import PatchNet, SlideNet
from worker.pipeline.cnn.normalize import dense_inputs, relative_patch_pair
from worker.pipeline.cnn.patches import centre_crop, centre_fractions, label_from_fraction

HALO_PX = 96  # > receptive-field radius (~66 px) + half the reference window (16 px)
DEFAULT_PIXEL_THRESHOLD = 0.5
MULTIPLE = 8


def torch_threads(num_threads: int) -> None:
    if num_threads and torch.get_num_threads() != num_threads:
        torch.set_num_threads(num_threads)


@torch.inference_mode()
def predict_patches(
    model: PatchNet,
    pre: np.ndarray,
    post: np.ndarray,
    pixel_size_m: float | np.ndarray,
    batch_size: int = 256,
) -> np.ndarray:
    """Landslide probability of each (N, 42, 42) patch pair (the centre crop is fed)."""
    model.eval()
    pre32, post32 = centre_crop(pre), centre_crop(post)
    size = np.asarray(pixel_size_m, dtype=np.float64)
    if size.ndim == 1:
        size = size[:, None, None]
    out = np.zeros(pre.shape[0], dtype=np.float32)
    for start in range(0, pre.shape[0], batch_size):
        sl = slice(start, start + batch_size)
        s = size[sl] if size.ndim == 3 else size
        a, b = relative_patch_pair(pre32[sl], post32[sl], s)
        x = torch.from_numpy(np.stack([a, b], axis=1))
        out[sl] = torch.sigmoid(model(x)).numpy()
    return out


@torch.inference_mode()
def _dense_window(
    model: SlideNet, pre_w: np.ndarray, post_w: np.ndarray, pixel_size_m: float
) -> np.ndarray:
    """Probabilities for a window (any size; padded to a multiple of 8 with nodata)."""
    h, w = pre_w.shape
    ph, pw = (-h) % MULTIPLE, (-w) % MULTIPLE
    if ph or pw:
        pre_w = np.pad(pre_w, ((0, ph), (0, pw)), constant_values=np.nan)
        post_w = np.pad(post_w, ((0, ph), (0, pw)), constant_values=np.nan)
    x = dense_inputs(pre_w, post_w, pixel_size_m)
    logits = model(torch.from_numpy(x)[None])[0]
    prob = torch.sigmoid(logits).numpy()[:h, :w]
    prob[x[3, :h, :w] == 0] = 0.0
    return prob


def block_mean(array: np.ndarray, factor: int) -> np.ndarray:
    """Mean of factor x factor blocks (the array is cropped to whole blocks); a block with
    any NaN is NaN."""
    if factor == 1:
        return array
    h, w = (array.shape[0] // factor) * factor, (array.shape[1] // factor) * factor
    blocks = array[:h, :w].reshape(h // factor, factor, w // factor, factor)
    return blocks.mean(axis=(1, 3), dtype=np.float64).astype(np.float32)


def pyramid_window(
    model: SlideNet,
    pre_w: np.ndarray,
    post_w: np.ndarray,
    pixel_size_m: float,
    scales: tuple[int, ...],
    halo: int,
    core: tuple[int, int],
) -> np.ndarray:
    """Test-time pyramid over a window read with `halo` = pyramid_halo(scales) around a
    core of `core` pixels: the model at each scale (block means, pixel size x scale) on
    the core plus HALO_PX x scale, upsampled bilinearly; the maximum over scales, for the
    core only. Returns (h, w) probabilities, 0 where either DSM has no data."""
    h, w = core
    out = np.zeros((h, w), dtype=np.float32)
    for scale in scales:
        own = HALO_PX * scale
        off = halo - own
        size = window_size(h, w, own, MULTIPLE * scale)
        pre_s = pre_w[off : off + size[0], off : off + size[1]]
        post_s = post_w[off : off + size[0], off : off + size[1]]
        if scale == 1:
            prob = _dense_window(model, pre_s, post_s, pixel_size_m)
        else:
            coarse = _dense_window(
                model, block_mean(pre_s, scale), block_mean(post_s, scale), pixel_size_m * scale
            )
            prob = cv2.resize(
                coarse, (pre_s.shape[1], pre_s.shape[0]), interpolation=cv2.INTER_LINEAR
            )
        np.maximum(out, prob[own : own + h, own : own + w], out=out)
    valid = np.isfinite(pre_w[halo : halo + h, halo : halo + w]) & np.isfinite(
        post_w[halo : halo + h, halo : halo + w]
    )
    out[~valid] = 0.0
    return out


def pyramid_halo(scales: tuple[int, ...]) -> int:
    """Full-resolution halo for a pyramid: HALO_PX at the coarsest scale."""
    return HALO_PX * max(scales)


def predict_dense(
    model: SlideNet,
    pre: np.ndarray,
    post: np.ndarray,
    pixel_size_m: float,
    tile_px: int = 1024,
    num_threads: int = 2,
    scales: tuple[int, ...] = (1,),
) -> np.ndarray:
    """Per-pixel landslide probability of in-memory arrays (0 where either has no data)."""
    torch_threads(num_threads)
    model.eval()
    height, width = pre.shape
    halo = pyramid_halo(scales)
    prob = np.zeros((height, width), dtype=np.float32)
    for r0, c0, h, w in tiles((height, width), tile_px, MULTIPLE * max(scales)):
        size = window_size(h, w, halo, max(scales))
        pre_w = crop_padded(pre, r0 - halo, c0 - halo, *size)
        post_w = crop_padded(post, r0 - halo, c0 - halo, *size)
        p = pyramid_window(model, pre_w, post_w, pixel_size_m, scales, halo, (h, w))
        prob[r0 : r0 + h, c0 : c0 + w] = p
    return prob


def window_size(h: int, w: int, halo: int, multiple: int) -> tuple[int, int]:
    """Tile plus halo, rounded up to a multiple of `multiple` (padding is nodata)."""
    return (
        math.ceil((h + 2 * halo) / multiple) * multiple,
        math.ceil((w + 2 * halo) / multiple) * multiple,
    )


def patch_scores_from_probability(
    probability: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    pixel_threshold: float = DEFAULT_PIXEL_THRESHOLD,
) -> tuple[np.ndarray, np.ndarray]:
    """For patches with origins rows x cols (1-D grids): the share of landslide pixels in
    each 32-pixel centre and the patch label by the paper's 10 % rule. Shapes
    (len(rows), len(cols))."""
    landslide = (probability >= pixel_threshold).astype(np.uint8)
    fraction = centre_fractions(landslide, rows, cols)
    return fraction, label_from_fraction(fraction)


def tiles(shape: tuple[int, int], tile_px: int, multiple: int = MULTIPLE):
    tile_px = max(multiple, (tile_px // multiple) * multiple)
    height, width = shape
    for r0 in range(0, height, tile_px):
        for c0 in range(0, width, tile_px):
            yield r0, c0, min(tile_px, height - r0), min(tile_px, width - c0)


def crop_padded(array: np.ndarray, r0: int, c0: int, h: int, w: int) -> np.ndarray:
    out = np.full((h, w), np.nan, dtype=np.float32)
    rs, cs = max(r0, 0), max(c0, 0)
    re, ce = min(r0 + h, array.shape[0]), min(c0 + w, array.shape[1])
    if re > rs and ce > cs:
        out[rs - r0 : re - r0, cs - c0 : ce - c0] = array[rs:re, cs:ce]
    return out


__all__ = [
    "HALO_PX",
    "MULTIPLE",
    "block_mean",
    "crop_padded",
    "patch_scores_from_probability",
    "predict_dense",
    "predict_patches",
    "pyramid_halo",
    "pyramid_window",
    "tiles",
    "torch_threads",
    "window_size",
]
