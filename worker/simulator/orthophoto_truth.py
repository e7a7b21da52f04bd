"""How far an orthophoto's features sit from the simulator's truth orthoimage.

The truth is drawn onto the orthophoto's grid, first moved by a global offset found at a
coarse scale (a stand-alone GNSS survey sits metres off, beyond what a fine tile can
see), then each tile of 128 cells is matched by phase correlation. The survey's own
georeferencing offset is the median of the tile shifts; what remains after it is the
orthophoto's error as a user sees it on a well-registered map, and what remains after a
2-D similarity (the georeference's rotation and scale, which the DSM carries equally) is
the orthophoto's own, local error.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import rasterio
from rasterio.transform import Affine
from rasterio.warp import Resampling, reproject


@dataclass
class OrthophotoErrors:
    tiles: int
    offset_px: tuple[float, float]  # the survey's offset (x east, y south), pixels
    residual_median_px: float  # after the offset
    residual_p90_px: float
    local_median_px: float  # after a 2-D similarity
    local_p90_px: float
    rotation_deg: float  # of that similarity
    scale_error: float
    correlation: float  # of grey levels where both have content
    pixel_m: float

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def _truth_on(truth: Path, transform: Affine, shape: tuple[int, int], crs: Any) -> np.ndarray:
    out = np.zeros((3, *shape), np.float32)
    with rasterio.open(truth) as src:
        for band in range(3):
            reproject(
                rasterio.band(src, band + 1),
                out[band],
                dst_transform=transform,
                dst_crs=crs,
                resampling=Resampling.average,
            )
    return out.mean(axis=0)


def tile_shifts(
    image: np.ndarray, reference: np.ndarray, valid: np.ndarray, n: int = 128
) -> tuple[np.ndarray, np.ndarray]:
    """Per n x n tile where both images have content: the shift (px) that carries the
    reference onto the image, and the tile's centre."""
    window = cv2.createHanningWindow((n, n), cv2.CV_32F)
    shifts, centres = [], []
    for r in range(0, image.shape[0] - n, n):
        for c in range(0, image.shape[1] - n, n):
            a, b = image[r : r + n, c : c + n], reference[r : r + n, c : c + n]
            if valid[r : r + n, c : c + n].mean() < 0.99 or b.min() == 0:
                continue
            (dx, dy), response = cv2.phaseCorrelate(b - b.mean(), a - a.mean(), window)
            if response > 0.1:
                shifts.append((dx, dy))
                centres.append((c + n / 2, r + n / 2))
    return np.array(shifts).reshape(-1, 2), np.array(centres).reshape(-1, 2)


def similarity_fit(centres: np.ndarray, shifts: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Residuals after a 2-D similarity fitted to the shifts; its rotation (degrees) and
    scale error."""
    x, y = centres.T
    one, zero = np.ones(len(x)), np.zeros(len(x))
    a = np.empty((2 * len(x), 4))
    a[0::2] = np.column_stack([x, -y, one, zero])
    a[1::2] = np.column_stack([y, x, zero, one])
    target = (centres + shifts).ravel()
    params, *_ = np.linalg.lstsq(a, target, rcond=None)
    residuals = np.hypot(*(a @ params - target).reshape(-1, 2).T)
    rotation = float(np.degrees(np.arctan2(params[1], params[0])))
    return residuals, rotation, float(np.hypot(params[0], params[1]) - 1.0)


def orthophoto_errors(
    orthophoto: Path, truth_ortho: Path, bias_xy: tuple[float, float] = (0.0, 0.0)
) -> OrthophotoErrors:
    """Compare `orthophoto` (RGBA) with the truth orthoimage moved by `bias_xy` metres
    (a known GNSS bias; the coarse search finds what is left)."""
    with rasterio.open(orthophoto) as src:
        rgba = src.read()
        transform, crs = src.transform, src.crs
    grey = rgba[:3].astype(np.float32).mean(axis=0)
    alpha = rgba[3] > 0
    shifted = transform * Affine.translation(-bias_xy[0] / transform.a, -bias_xy[1] / transform.e)
    reference = _truth_on(truth_ortho, shifted, grey.shape, crs)
    # A coarse offset first: 1/8 of the resolution, the whole image at once.
    factor = 8
    small = (max(1, grey.shape[1] // factor), max(1, grey.shape[0] // factor))
    a = cv2.resize(grey, small, interpolation=cv2.INTER_AREA)
    b = cv2.resize(reference, small, interpolation=cv2.INTER_AREA)
    seen = cv2.resize(alpha.astype(np.float32), small) > 0.99
    if seen.sum() > 64:
        a0 = np.where(seen, a - a[seen].mean(), 0).astype(np.float32)
        b0 = np.where(seen, b - b[seen].mean(), 0).astype(np.float32)
        (cx, cy), _ = cv2.phaseCorrelate(b0, a0)
        shifted = shifted * Affine.translation(-cx * factor, -cy * factor)
        reference = _truth_on(truth_ortho, shifted, grey.shape, crs)
    shifts, centres = tile_shifts(grey, reference, alpha)
    both = alpha & (reference > 0)
    correlation = float(np.corrcoef(grey[both], reference[both])[0, 1]) if both.sum() > 10 else 0.0
    if len(shifts) < 3:
        nan = float("nan")
        return OrthophotoErrors(len(shifts), (nan, nan), nan, nan, nan, nan, nan, nan,
                                correlation, abs(transform.a))  # fmt: skip
    offset = np.median(shifts, axis=0)
    residual = np.hypot(*(shifts - offset).T)
    local, rotation, scale = similarity_fit(centres, shifts - offset)
    return OrthophotoErrors(
        tiles=len(shifts),
        offset_px=(round(float(offset[0]), 3), round(float(offset[1]), 3)),
        residual_median_px=round(float(np.median(residual)), 3),
        residual_p90_px=round(float(np.percentile(residual, 90)), 3),
        local_median_px=round(float(np.median(local)), 3),
        local_p90_px=round(float(np.percentile(local, 90)), 3),
        rotation_deg=round(rotation, 4),
        scale_error=round(scale, 5),
        correlation=round(correlation, 4),
        pixel_m=abs(transform.a),
    )
