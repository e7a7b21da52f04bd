"""Input normalisation: elevations relative to the patch, in units of the DSM pixel size.

One model must serve 2 cm and 20 cm DSMs (the paper's one-tenth-scale field and real
slopes). Both scales look alike once heights are measured in pixel sizes: a 1.5 m mound at
2 cm/pixel and a 15 m slope at 20 cm/pixel are both 75 units high, and the paper's
quantisation of 1.2 cm per grey level at 2 cm/pixel is 0.6 units. So every model input is

    (z - reference) / pixel_size_m

Patch models (`PatchNet`, the paper's protocol): the reference is the mean of the valid
pixels of the pre patch as it is fed to the model (after any crop and vertical offset),
subtracted from BOTH channels, so that the post - pre difference survives unchanged.

Dense models (`SlideNet`): there is no patch, so the reference is the local mean of the
pre DSM over a `REFERENCE_WINDOW_PX` square window (a box filter, nodata ignored). The
channels are:

    0  rel_pre  = (pre - local_mean(pre)) / pixel_size
    1  rel_post = (post - local_mean(pre)) / pixel_size
    2  dh       = (post - pre) / pixel_size
    3  valid    = 1 where both DSMs have elevations, else 0

Elevation channels are clipped to +-`CLIP_UNITS` and multiplied by `DENSE_SCALE` so that
typical values are of order one; invalid pixels are 0 in every channel.
"""

from __future__ import annotations

import cv2
import numpy as np

CLIP_UNITS = 256.0  # pixel sizes; a 1.5 m drop at 2 cm is 75 units
DENSE_SCALE = 1.0 / 16.0
REFERENCE_WINDOW_PX = 33
DENSE_CHANNELS = ("rel_pre", "rel_post", "dh", "valid")


def relative_patch_pair(
    pre: np.ndarray, post: np.ndarray, pixel_size_m: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Normalise patch pairs for the patch models.

    `pre`, `post`: arrays (..., H, W) in metres; `pixel_size_m` a number or an array that
    broadcasts against (..., 1, 1). Returns float32 arrays of the same shape in pixel
    units relative to the mean of each pre patch; NaN (nodata) becomes 0 (the reference),
    so a hole reads as flat ground at the patch's mean height.
    """
    pixel_size_m = np.asarray(pixel_size_m, dtype=np.float64)
    if np.any(pixel_size_m <= 0):
        raise ValueError("the pixel size must be positive")
    pre = np.asarray(pre, dtype=np.float64)
    post = np.asarray(post, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        reference = np.nanmean(pre, axis=(-2, -1), keepdims=True)
    reference = np.where(np.isfinite(reference), reference, 0.0)
    rel_pre = (pre - reference) / pixel_size_m
    rel_post = (post - reference) / pixel_size_m
    rel_pre = np.clip(np.nan_to_num(rel_pre, nan=0.0), -CLIP_UNITS, CLIP_UNITS)
    rel_post = np.clip(np.nan_to_num(rel_post, nan=0.0), -CLIP_UNITS, CLIP_UNITS)
    return rel_pre.astype(np.float32), rel_post.astype(np.float32)


def local_mean(array: np.ndarray, window_px: int = REFERENCE_WINDOW_PX) -> np.ndarray:
    """Mean of the valid (finite) values in a square window around each pixel.

    Pixels whose window holds no valid value get NaN. Borders use reflection.
    """
    valid = np.isfinite(array)
    values = np.where(valid, array, 0.0).astype(np.float64)
    size = (window_px, window_px)
    total = cv2.boxFilter(values, -1, size, normalize=False, borderType=cv2.BORDER_REFLECT)
    count = cv2.boxFilter(
        valid.astype(np.float64), -1, size, normalize=False, borderType=cv2.BORDER_REFLECT
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
    mean[count < 0.5] = np.nan
    return mean


def dense_inputs(
    pre: np.ndarray, post: np.ndarray, pixel_size_m: float, reference: np.ndarray | None = None
) -> np.ndarray:
    """The (4, H, W) float32 input of the dense models for one pre/post pair in metres.

    `reference` (the local mean of pre) may be given when the caller computed it on a
    larger window than it passes here, e.g. tiles with a halo.
    """
    if pixel_size_m <= 0:
        raise ValueError("the pixel size must be positive")
    pre = np.asarray(pre, dtype=np.float64)
    post = np.asarray(post, dtype=np.float64)
    if reference is None:
        reference = local_mean(pre)
    valid = np.isfinite(pre) & np.isfinite(post) & np.isfinite(reference)
    out = np.zeros((4, *pre.shape), dtype=np.float32)
    with np.errstate(invalid="ignore"):
        channels = (
            (pre - reference) / pixel_size_m,
            (post - reference) / pixel_size_m,
            (post - pre) / pixel_size_m,
        )
    for i, channel in enumerate(channels):
        clipped = np.clip(np.where(valid, channel, 0.0), -CLIP_UNITS, CLIP_UNITS)
        out[i] = clipped * DENSE_SCALE
    out[3] = valid
    return out


def vertical_level_m(pixel_size_m: float) -> float:
    """The paper's grey level (1.2 cm at 2 cm/pixel) scaled with the pixel size: 0.6 px."""
    return 0.6 * pixel_size_m
