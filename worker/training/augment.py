"""Augmentation: the paper's fixed and loose crops, flips, and registration error.

Fixed training (paper): the 32-pixel centre of both 42-pixel patches, i.e. rows and
columns 5..36.

Loose training (paper, Fig. 7): the post patch is cropped at the centre; the PRE patch is
cropped at a random offset (dy, dx), each an integer drawn uniformly from -5..5, so it
stays inside the 5-pixel margin, and a random vertical offset of k grey levels is added
to it, k an integer drawn uniformly from -10..10. A grey level is the paper's 1.2 cm at
2 cm/pixel, scaled with the pixel size: 0.6 pixel sizes (so +-0.12 m at 2 cm/pixel and
+-1.2 m at 20 cm/pixel, the registration error of Table 2).

Flips (paper, Table 3): horizontal and vertical flips, each with probability 1/2, applied
identically to both channels.

Dense training (`registration_jitter`, ours): the post tile is resampled at a random
horizontal offset (continuous, bilinear) and raised by a random vertical offset, so the
dense model sees the residual misregistration left after co-registration.
"""

from __future__ import annotations

import cv2
import numpy as np

from worker.pipeline.cnn.normalize import vertical_level_m
from worker.pipeline.cnn.patches import CORE_PX, MARGIN_PX, centre_crop

MAX_LEVELS = 10  # the paper's +-10 grey levels


def fixed_crop(pre: np.ndarray, post: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fixed training and all inference: the centres of both patches."""
    return centre_crop(pre), centre_crop(post)


def loose_crop(
    pre: np.ndarray,
    post: np.ndarray,
    pixel_size_m: np.ndarray | float,
    rng: np.random.Generator,
    max_shift_px: int = MARGIN_PX,
    max_levels: int = MAX_LEVELS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Loose training crop of a batch of (N, 42, 42) patch pairs.

    Returns (pre32, post32, shifts (N, 2) int as (dy, dx), offsets_m (N,)). The pre crop
    starts at rows 5+dy, cols 5+dx; offsets_m = k * 0.6 * pixel size is added to pre.
    """
    n = pre.shape[0]
    shifts = rng.integers(-max_shift_px, max_shift_px + 1, size=(n, 2))
    levels = rng.integers(-max_levels, max_levels + 1, size=n)
    level_m = vertical_level_m(1.0) * np.broadcast_to(np.asarray(pixel_size_m, np.float64), (n,))
    offsets = levels * level_m
    pre32 = np.empty((n, CORE_PX, CORE_PX), dtype=np.float32)
    for i in range(n):
        r = MARGIN_PX + int(shifts[i, 0])
        c = MARGIN_PX + int(shifts[i, 1])
        pre32[i] = pre[i, r : r + CORE_PX, c : c + CORE_PX] + offsets[i]
    return pre32, centre_crop(post).astype(np.float32), shifts, offsets


def random_flips(
    rng: np.random.Generator, *arrays: np.ndarray
) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """Flip each sample (first axis) of every array alike along its last two axes.

    Returns the flipped arrays and the flags (N, 2) (vertical, horizontal).
    """
    n = arrays[0].shape[0]
    flags = rng.random((n, 2)) < 0.5
    out = []
    for array in arrays:
        flipped = array.copy()
        flipped[flags[:, 0]] = flipped[flags[:, 0]][..., ::-1, :]
        flipped[flags[:, 1]] = flipped[flags[:, 1]][..., :, ::-1]
        out.append(flipped)
    return tuple(out), flags


def registration_jitter(
    post_window: np.ndarray,
    out_shape: tuple[int, int],
    halo: int,
    shift_px: tuple[float, float],
    offset_m: float,
) -> np.ndarray:
    """Post tile resampled at a horizontal offset, plus a vertical offset.

    `post_window` covers the output tile plus `halo` pixels on each side. The output
    pixel (i, j) takes post at (i + halo + dy, j + halo + dx), bilinear; NaN stays NaN
    (any NaN neighbour makes the output NaN).
    """
    dy, dx = shift_px
    if abs(dy) > halo or abs(dx) > halo:
        raise ValueError("the shift must stay within the halo")
    valid = np.isfinite(post_window)
    filled = np.where(valid, post_window, 0.0).astype(np.float32)
    matrix = np.array([[1.0, 0.0, halo + dx], [0.0, 1.0, halo + dy]], dtype=np.float64)
    size = (out_shape[1], out_shape[0])
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    moved = cv2.warpAffine(filled, matrix, size, flags=flags)
    weight = cv2.warpAffine(valid.astype(np.float32), matrix, size, flags=flags)
    moved = moved.astype(np.float64) + offset_m
    moved[weight < 0.999] = np.nan
    return moved
