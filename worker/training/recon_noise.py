"""An interim model of reconstruction noise, for training before reconstructed DSMs exist.

The paper trains on DSO-derived DSMs: a sparse point cloud, averaged per grid cell, the
empty cells filled by Fast-Marching inpainting, exported at 1.2 cm per grey level
(Fig. 9 shows that their difference still holds many noise areas at a 30 cm threshold).
Until slidewatch's reconstruction produces DSMs from simulated video, training DSMs are
the simulator's truth DSMs passed through this model, which imitates that process step by
step (all sizes in DSM pixels or pixel sizes, so it scales from 2 cm to 20 cm DSMs):

1. A smooth error field (correlated noise of the sparse reconstruction and of the
   georeferencing at short range): std `correlated_sigma_px` pixel sizes, correlation
   length about `correlation_px` pixels.
2. Point noise: std `point_sigma_px` pixel sizes per cell; and points placed slightly
   off horizontally (a smooth displacement field of std `horizontal_sigma_px` pixels),
   which makes an error of slope x displacement on steep ground.
3. Sparse coverage: a cell holds a point with a probability that varies smoothly between
   `coverage` (texture-rich vs. poor ground) and falls on rough surfaces (crowns, edges),
   where direct methods track few points. Large holes (discs of radius `gap_radius_px`,
   `gaps_per_mpx` per million pixels) model occlusions and texture-poor patches.
4. Outliers that survived the outlier removal: small blobs (radius 1-3 pixels) raised or
   lowered by `outlier_px` pixel sizes, `outliers_per_mpx` per million pixels; and
   blunders, smooth gaussian bumps (sigma `blunder_sigma_px`, height `blunder_px` pixel
   sizes, `blunders_per_mpx`) where a patch of points was tracked at a wrong depth.
5. Quantisation to the export's grey levels: `level_px` = 0.6 pixel sizes (1.2 cm at
   2 cm/pixel).
6. Fast-Marching (Telea) inpainting of the empty cells (OpenCV), as the paper does.

With the defaults, the difference of two independently degraded copies of one 2 cm DSM
has an NMAD of about 3 cm and exceeds 20 cm on a few per cent of the mound pixels, in
blobs: noise of the kind the paper's Fig. 9 shows for DSO. It is a stand-in; the model
card of every model trained on it says so.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np


@dataclass(frozen=True)
class ReconstructionNoise:
    correlated_sigma_px: float = 1.5
    correlation_px: float = 30.0
    point_sigma_px: float = 0.6
    horizontal_sigma_px: float = 1.5
    horizontal_correlation_px: float = 50.0
    coverage: tuple[float, float] = (0.3, 0.9)
    coverage_scale_px: float = 60.0
    roughness_drop: float = 0.5  # coverage *= exp(-drop * roughness in pixel sizes)
    gaps_per_mpx: float = 20.0
    gap_radius_px: tuple[float, float] = (6.0, 25.0)
    outliers_per_mpx: float = 600.0
    outlier_px: tuple[float, float] = (5.0, 20.0)
    blunders_per_mpx: float = 60.0
    blunder_sigma_px: tuple[float, float] = (4.0, 14.0)
    blunder_px: tuple[float, float] = (5.0, 25.0)
    level_px: float = 0.6
    inpaint_radius_px: int = 5

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def smooth_field(shape: tuple[int, int], scale_px: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean, unit-std random field with features about `scale_px` pixels across."""
    height, width = shape
    step = max(scale_px / 2.0, 1.0)
    coarse = rng.standard_normal((int(height / step) + 4, int(width / step) + 4)).astype(np.float32)
    big = cv2.resize(
        coarse,
        (round(coarse.shape[1] * step), round(coarse.shape[0] * step)),
        interpolation=cv2.INTER_CUBIC,
    )
    field = big[:height, :width].astype(np.float64)
    field -= field.mean()
    std = field.std()
    return field / std if std > 0 else field


def degrade(
    dsm: np.ndarray,
    pixel_size_m: float,
    rng: np.random.Generator,
    noise: ReconstructionNoise | None = None,
) -> np.ndarray:
    """A reconstruction-like copy of a truth DSM (metres, NaN = nodata), float32."""
    noise = noise or ReconstructionNoise()
    shape = dsm.shape
    px = float(pixel_size_m)
    valid = np.isfinite(dsm)
    if not valid.any():
        return dsm.astype(np.float32)
    base = float(np.nanmin(dsm))
    z = np.where(valid, dsm, base).astype(np.float64) - base

    # 1-2: smooth error and point noise.
    z_obs = z + px * noise.correlated_sigma_px * smooth_field(shape, noise.correlation_px, rng)
    z_obs += px * noise.point_sigma_px * rng.standard_normal(shape)
    # Points placed slightly off horizontally: an error of slope x displacement.
    grad_r, grad_c = np.gradient(z)
    for grad in (grad_r, grad_c):
        shift = noise.horizontal_sigma_px * smooth_field(
            shape, noise.horizontal_correlation_px, rng
        )
        z_obs += grad * shift

    # 3: sparse coverage.
    lo, hi = noise.coverage
    field = smooth_field(shape, noise.coverage_scale_px, rng)
    probability = lo + (hi - lo) * (0.5 + 0.5 * np.tanh(field))
    blurred = cv2.GaussianBlur(z.astype(np.float32), (0, 0), 1.5).astype(np.float64)
    roughness = np.abs(z - blurred) / px
    probability *= np.exp(-noise.roughness_drop * roughness)
    observed = rng.random(shape) < probability
    megapixels = shape[0] * shape[1] / 1e6
    holes = np.zeros(shape, dtype=np.uint8)
    for _ in range(rng.poisson(noise.gaps_per_mpx * megapixels)):
        r = rng.uniform(*noise.gap_radius_px)
        centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
        axes = (round(r), round(r * rng.uniform(0.5, 1.0)))
        cv2.ellipse(holes, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    observed &= holes == 0

    # 4: outlier blobs.
    bumps = np.zeros(shape, dtype=np.float32)
    for _ in range(rng.poisson(noise.outliers_per_mpx * megapixels)):
        centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
        value = float(rng.choice([-1.0, 1.0]) * rng.uniform(*noise.outlier_px) * px)
        cv2.circle(bumps, centre, int(rng.integers(1, 4)), value, -1)
    z_obs += bumps
    # Blunders: smooth bumps where a patch of points was placed at a wrong depth.
    rows, cols = np.ogrid[: shape[0], : shape[1]]
    for _ in range(rng.poisson(noise.blunders_per_mpx * megapixels)):
        sigma = rng.uniform(*noise.blunder_sigma_px)
        r0, c0 = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        half = int(3 * sigma) + 1
        rs = slice(max(r0 - half, 0), min(r0 + half + 1, shape[0]))
        cs = slice(max(c0 - half, 0), min(c0 + half + 1, shape[1]))
        value = float(rng.choice([-1.0, 1.0]) * rng.uniform(*noise.blunder_px) * px)
        d2 = (rows[rs] - r0) ** 2 + (cols[:, cs] - c0) ** 2
        z_obs[rs, cs] += value * np.exp(-d2 / (2 * sigma**2))

    # 5-6: grey levels (uint16 counts, like the paper's grey-scale export), then
    # Fast-Marching inpainting of the empty cells. OpenCV's Telea inpainting is used on
    # the integer levels: on float32 input it returns wrong values (OpenCV 5.0).
    level = noise.level_px * px
    counts = np.round(z_obs / level)
    offset = 16.0 - float(counts.min())
    counts = np.clip(counts + offset, 0, np.iinfo(np.uint16).max).astype(np.uint16)
    missing = (~observed).astype(np.uint8)
    filled = cv2.inpaint(counts, missing, noise.inpaint_radius_px, cv2.INPAINT_TELEA)
    out = (filled.astype(np.float64) - offset) * level + base
    out[~valid] = np.nan
    return out.astype(np.float32)
