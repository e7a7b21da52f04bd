"""A first horizontal shift between two DSMs by phase correlation, before Nuth & Kääb.

Nuth & Kääb refines a shift from the slopes of the terrain and converges only when the
DSMs are already closer than the features they share: two flights with stand-alone GNSS
can be metres apart, more than a sand mound or a gully is wide, and then it settles on a
wrong shift. Phase correlation finds the translation from the whole pattern at once.

Both DSMs are reduced to at most `max_size_px` on their long side (block means that
ignore nodata), detrended by subtracting a wide Gaussian smoothing (which removes the
vertical offset and any tilt), tapered by a Hann window, and correlated with
`cv2.phaseCorrelate`. The result is the correction to apply to post (the opposite of its
displacement), in metres, with the correlation peak's response; a weak peak (below
`min_response`) gives no shift, and Nuth & Kääb alone decides.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class CoarseShift:
    east_m: float
    north_m: float
    response: float  # height of the correlation peak, 0..1
    used: bool  # strong enough to be applied


def _block_mean(array: np.ndarray, factor: int) -> np.ndarray:
    """Mean of each factor x factor block, ignoring NaN (NaN where a block has none)."""
    if factor <= 1:
        return array.astype(np.float32)
    rows, cols = (array.shape[0] // factor) * factor, (array.shape[1] // factor) * factor
    blocks = array[:rows, :cols].reshape(rows // factor, factor, cols // factor, factor)
    valid = np.isfinite(blocks)
    total = np.where(valid, blocks, 0.0).sum(axis=(1, 3), dtype=np.float64)
    count = valid.sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        return (total / count).astype(np.float32)


def _pattern(dsm: np.ndarray, valid: np.ndarray, sigma_px: float) -> np.ndarray:
    """The DSM's relief around its own smoothed surface; 0 outside `valid`."""
    filled = np.where(valid, dsm, 0.0).astype(np.float32)
    weight = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), sigma_px)
    smooth = cv2.GaussianBlur(filled, (0, 0), sigma_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        trend = np.where(weight > 1e-3, smooth / weight, 0.0)
    return np.where(valid, filled - trend, 0.0).astype(np.float32)


def coarse_shift(
    pre: np.ndarray,
    post: np.ndarray,
    res_x: float,
    res_y: float,
    max_size_px: int = 1024,
    detrend_sigma_px: float = 8.0,
    min_response: float = 0.05,
) -> CoarseShift:
    """The correction (east, north) in metres that moves post onto pre, found by phase
    correlation at reduced resolution (see the module doc); NaN is nodata."""
    factor = max(1, int(np.ceil(max(pre.shape) / max_size_px)))
    small_pre, small_post = _block_mean(pre, factor), _block_mean(post, factor)
    valid_pre, valid_post = np.isfinite(small_pre), np.isfinite(small_post)
    if min(small_pre.shape) < 16 or valid_pre.mean() < 0.05 or valid_post.mean() < 0.05:
        return CoarseShift(0.0, 0.0, 0.0, False)
    window = cv2.createHanningWindow(small_pre.shape[::-1], cv2.CV_32F)
    a = _pattern(small_pre, valid_pre, detrend_sigma_px)
    b = _pattern(small_post, valid_post, detrend_sigma_px)
    (dx, dy), response = cv2.phaseCorrelate(a, b, window)
    # (dx, dy): where post's pattern lies relative to pre's, in reduced pixels (x east,
    # y south); the correction is the opposite.
    east, north = -dx * factor * res_x, dy * factor * res_y
    used = bool(response >= min_response)
    return CoarseShift(float(east), float(north), float(response), used)
