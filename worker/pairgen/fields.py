"""Random fields and smoothing shared by the terrain, surface and error models.

Spectral synthesis by FFT: the cost is one FFT pair whatever the correlation length,
which keeps a 640 x 640 pair well under a second.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage


@lru_cache(maxsize=4)
def _radial_frequency(shape: tuple[int, int], pixel_size: float) -> np.ndarray:
    """|k| in cycles per metre on the rfft2 half-plane (read-only: it is shared)."""
    ky = np.fft.fftfreq(shape[0], d=pixel_size)
    kx = np.fft.rfftfreq(shape[1], d=pixel_size)
    k = np.hypot(ky[:, None], kx[None, :]).astype(np.float32)
    k.flags.writeable = False
    return k


def _synthesis_shape(shape: tuple[int, int]) -> tuple[int, int]:
    """A grid a quarter larger, of FFT-friendly sizes, to cut the field from.

    The margin keeps opposite edges of the field from matching (the synthesis is
    periodic); the friendly size matters because a prime side (541) is ten times slower.
    """
    return (
        sp_fft.next_fast_len(shape[0] + shape[0] // 4, real=True),
        sp_fft.next_fast_len(shape[1] + shape[1] // 4, real=True),
    )


def _from_spectrum(
    shape: tuple[int, int],
    pixel_size: float,
    amplitude: Callable[[np.ndarray], np.ndarray],
    rng: np.random.Generator,
) -> np.ndarray:
    """Zero-mean, unit-std field whose Fourier amplitude is amplitude(|k|).

    Synthesised in single precision (twice as fast; a random field needs no more) and
    returned as float64.
    """
    big = _synthesis_shape(shape)
    k = _radial_frequency(big, float(pixel_size))
    a = amplitude(k).astype(np.float32)
    a[0, 0] = 0.0
    white = rng.standard_normal(big, dtype=np.float32)
    field = sp_fft.irfft2(sp_fft.rfft2(white) * a, s=big)[: shape[0], : shape[1]]
    field = field.astype(np.float64)
    field -= field.mean()
    std = field.std()
    return field / std if std > 0 else field


def power_law_field(
    shape: tuple[int, int],
    pixel_size: float,
    rng: np.random.Generator,
    beta: float,
    outer_m: float,
    inner_m: float = 0.0,
) -> np.ndarray:
    """Unit-std field with power spectrum ~ |k|^-beta between 1/outer_m and 1/inner_m.

    Below 1/outer_m the spectrum flattens (no energy runs off to the grid scale); above
    1/inner_m a Gaussian taper removes detail finer than inner_m, so slopes computed on
    the field do not depend on the pixel size.
    """
    k0 = 1.0 / outer_m

    def amplitude(k: np.ndarray) -> np.ndarray:
        a = (k * k + k0 * k0) ** (-beta / 4.0)
        return a * np.exp(-((k * inner_m) ** 2)) if inner_m > 0 else a

    return _from_spectrum(shape, pixel_size, amplitude, rng)


def gaussian_field(
    shape: tuple[int, int], pixel_size: float, rng: np.random.Generator, corr_m: float
) -> np.ndarray:
    """Unit-std field with a Gaussian correlation of e-folding length ~corr_m."""
    return _from_spectrum(
        shape, pixel_size, lambda k: np.exp(-((np.pi * k * corr_m) ** 2) / 2.0), rng
    )


def smooth(z: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian smoothing that stays cheap for large sigma.

    Large kernels are run on a block-averaged copy and interpolated back: a direct
    75-pixel Gaussian on 640 x 640 takes ~0.2 s, ten times this.
    Edges are extended (`nearest`), not wrapped: terrain has a regional slope, and a
    wrapped edge would invent a cliff there.
    """
    if sigma_px <= 4.0:
        return ndimage.gaussian_filter(z, sigma_px, mode="nearest")
    factor = int(sigma_px // 2.0)
    rows, cols = z.shape
    pr, pc = (-rows) % factor, (-cols) % factor
    padded = np.pad(z, ((0, pr), (0, pc)), mode="edge")
    coarse = padded.reshape(
        padded.shape[0] // factor, factor, padded.shape[1] // factor, factor
    ).mean(axis=(1, 3))
    # The block mean already blurs by ~factor/sqrt(12); the rest comes from the filter.
    rest = max(sigma_px**2 - factor**2 / 12.0, 1.0) ** 0.5 / factor
    coarse = ndimage.gaussian_filter(coarse, rest, mode="nearest")
    rr = (np.arange(rows) - (factor - 1) / 2.0) / factor
    cc = (np.arange(cols) - (factor - 1) / 2.0) / factor
    grid = np.meshgrid(rr, cc, indexing="ij")
    return ndimage.map_coordinates(coarse, grid, order=1, mode="nearest")


def gradient(z: np.ndarray, pixel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """dz/drow, dz/dcol in metres per metre (row 0 is north)."""
    d_row, d_col = np.gradient(z, pixel_size)
    return d_row, d_col


def slope_deg(z: np.ndarray, pixel_size: float) -> np.ndarray:
    d_row, d_col = gradient(z, pixel_size)
    return np.degrees(np.arctan(np.hypot(d_row, d_col)))


def rms_gradient(z: np.ndarray, pixel_size: float) -> float:
    d_row, d_col = gradient(z, pixel_size)
    return float(np.sqrt(np.mean(d_row**2 + d_col**2)))


def smoothstep(x: np.ndarray) -> np.ndarray:
    """0 below 0, 1 above 1, C1-smooth between: soft edges for scarps, risers, banks."""
    t = np.clip(x, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
