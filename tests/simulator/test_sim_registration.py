"""The injected registration shifts can be recovered from the truth DSMs."""

import cv2
import numpy as np
import pytest
from scipy import ndimage
from simtest_support import read_raster, short_run

from worker.simulator.registration import PAPER_PATTERNS, registration_patterns, shift_dsm
from worker.simulator.texture import fbm


def estimate_shift(ref: np.ndarray, moved: np.ndarray, refine: bool = False) -> tuple[float, float]:
    """(dcol, drow) such that moved(r, c) ~ ref(r - drow, c - dcol), by phase correlation
    of the mean-removed, Hanning-windowed DSMs; optionally refined by Gauss-Newton
    (Lucas-Kanade) on smooth surfaces, where the phase-correlation peak fit is biased
    for fractional shifts."""
    a = ref - ref.mean()
    b = moved - moved.mean()
    win = cv2.createHanningWindow(a.shape[::-1], cv2.CV_64F)
    (dc, dr), _ = cv2.phaseCorrelate(a, b, win)
    if refine:
        gy, gx = np.gradient(a)
        inner = (slice(16, -16), slice(16, -16))
        jx, jy = gx[inner].ravel(), gy[inner].ravel()
        jtj = np.array([[jx @ jx, jx @ jy], [jx @ jy, jy @ jy]])
        for _ in range(10):
            # b sampled at (r + dr, c + dc) equals a where the shift is right.
            bb = ndimage.shift(b, (-dr, -dc), order=3, mode="nearest")
            res = (bb - a)[inner].ravel()
            step = np.linalg.solve(jtj, -np.array([jx @ res, jy @ res]))
            dc, dr = dc + step[0], dr + step[1]
            if np.hypot(*step) < 1e-4:
                break
    return float(dc), float(dr)


def test_patterns_are_the_papers():
    assert PAPER_PATTERNS["C"] == (0.10, 0.10, 0.12)
    assert registration_patterns(10.0)["D"] == pytest.approx((1.0, 1.0, -1.2))


def test_fractional_shift_is_recovered():
    rng = np.random.default_rng(0)
    res = 0.02
    dsm = (25.0 + 0.3 * fbm((400, 400), rng, [40.0, 12.0], [0.7, 0.3])).astype(np.float64)
    shift = (0.37 * res, -0.21 * res, 0.05)
    moved = shift_dsm(dsm, res, shift)
    dc, dr = estimate_shift(dsm, moved, refine=True)
    assert dc == pytest.approx(0.37, abs=0.02)
    assert dr == pytest.approx(0.21, abs=0.02)  # north is up: rows decrease
    inner = (slice(40, -40), slice(40, -40))
    back = shift_dsm(moved, res, (-shift[0], -shift[1], 0.0))
    assert np.median((back - dsm)[inner]) == pytest.approx(0.05, abs=2e-3)


def test_pattern_shifts_are_recovered_from_the_written_dsms():
    run = short_run()
    reg = run.data["registration"]
    assert [r["pattern"] for r in reg] == ["A", "B", "C", "D"]
    res = run.data["grid"]["res_m"]
    base, *_ = read_raster(run.root / reg[0]["unshifted_dsm"])
    # A window around the mounds (structure in every direction).
    rows, cols = slice(500, 1300), slice(500, 1300)
    ref = base[rows, cols].astype(np.float64)
    for r in reg:
        moved_full, *_ = read_raster(run.root / r["shifted_dsm"])
        moved = moved_full[rows, cols].astype(np.float64)
        de, dn, du = r["shift_enu_m"]
        dc, dr = estimate_shift(ref, moved)
        assert dc == pytest.approx(de / res, abs=0.01), r["pattern"]
        assert dr == pytest.approx(-dn / res, abs=0.01), r["pattern"]
        ic, ir = round(dc), round(dr)
        h, w = ref.shape
        a = ref[max(0, -ir) : h - max(0, ir), max(0, -ic) : w - max(0, ic)]
        b = moved[max(0, ir) : h + min(0, ir), max(0, ic) : w + min(0, ic)]
        assert np.median(b - a) == pytest.approx(du, abs=1e-3), r["pattern"]
