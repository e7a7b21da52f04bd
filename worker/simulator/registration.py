"""Registration error injection for DSM pairs.

The paper tests its detector on four registration-error patterns (Table 4) at
one-tenth scale; at full scale the shifts are ten times larger (Table 2). A shift
(dE, dN, dU) moves the whole surface: the shifted DSM on the same grid is
``new(x, y) = old(x - dE, y - dN) + dU``, resampled with cubic splines (exactly, by
whole cells, when the shift is a whole number of cells).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

PAPER_PATTERNS: dict[str, tuple[float, float, float]] = {
    "A": (0.0, 0.0, 0.0),
    "B": (0.10, 0.10, 0.0),
    "C": (0.10, 0.10, 0.12),
    "D": (0.10, 0.10, -0.12),
}


def registration_patterns(scale: float = 1.0) -> dict[str, tuple[float, float, float]]:
    """The paper's patterns A-D at one-tenth scale times `scale` (10 for full scale)."""
    return {k: (v[0] * scale, v[1] * scale, v[2] * scale) for k, v in PAPER_PATTERNS.items()}


def shift_dsm(
    dsm: np.ndarray, res: float, shift_enu: tuple[float, float, float], order: int = 3
) -> np.ndarray:
    """The DSM as it would be exported with a registration error `shift_enu` (metres)."""
    de, dn, du = shift_enu
    cols = de / res  # east: content moves to larger columns
    rows = -dn / res  # north: content moves to smaller rows
    src = np.asarray(dsm, dtype=np.float64)
    if abs(cols - round(cols)) < 1e-9 and abs(rows - round(rows)) < 1e-9:
        out = _integer_shift(src, round(rows), round(cols))
    else:
        out = ndimage.shift(src, (rows, cols), order=order, mode="nearest")
    return (out + du).astype(dsm.dtype)


def _integer_shift(a: np.ndarray, dr: int, dc: int) -> np.ndarray:
    """out[r, c] = a[r - dr, c - dc], edges extended."""
    h, w = a.shape
    rr = np.clip(np.arange(h) - dr, 0, h - 1)
    cc = np.clip(np.arange(w) - dc, 0, w - 1)
    return a[rr][:, cc]
