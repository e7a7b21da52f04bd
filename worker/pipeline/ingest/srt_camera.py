"""Camera settings of DJI SRT files (f-number, ISO, focal length), with their scale traps.

`focal_len` has no single scale: `24.00` (mm, 35-mm equivalent), `240` (tenths of mm,
old firmware of the Mavic 2 / Air 2 families) and `643.30` (a zoom lens) all occur.
A wrong focal length silently ruins the camera model, so only plausible values are
reported, a zooming recording reports none, and every correction is warned about.
"""

from __future__ import annotations

from typing import Any

import numpy as np

# Families whose older firmware writes focal_len in tenths of mm as a whole number.
_TENTHS_FAMILIES = ("mavic2", "air2")
# A 35-mm equivalent focal length outside this range is no real drone camera.
FOCAL_35MM_RANGE = (10.0, 1000.0)
# Values varying by more than this ratio within one recording mean the lens zoomed.
_ZOOM_RATIO = 1.02


def camera_settings(
    rows: list[dict[str, Any]], variant: str, name: str, warnings: list[str]
) -> dict[str, float]:
    """Median f-number, ISO and 35-mm focal length of the recording, for `meta`."""
    meta: dict[str, float] = {}
    fnums = [r["fnum"] for r in rows if r.get("fnum") is not None]
    if fnums and float(np.median(fnums)) >= 50:  # `fnum 280` means f/2.8
        fnums = [f / 100.0 for f in fnums]
        warnings.append(f"{name}: fnum written in hundredths (old firmware); divided by 100")
    if fnums:
        meta["fnum"] = float(np.median(fnums))
    isos = [r["iso"] for r in rows if r.get("iso") is not None]
    if isos:
        meta["iso"] = float(np.median(isos))
    focal = _focal_35mm(rows, variant, name, warnings)
    if focal is not None:
        meta["focal_len_35mm"] = focal
    return meta


def _focal_35mm(
    rows: list[dict[str, Any]], variant: str, name: str, warnings: list[str]
) -> float | None:
    focals = []
    tenths = False
    for r in rows:
        value = r.get("focal_len")
        if value is None:
            continue
        if variant in _TENTHS_FAMILIES and r.get("focal_integer") and value >= 100:
            value, tenths = value / 10.0, True
        focals.append(value)
    if tenths:
        warnings.append(f"{name}: focal_len written in tenths of mm (old firmware); divided by 10")
    low, high = FOCAL_35MM_RANGE
    wrong = sorted({f for f in focals if not low <= f <= high})
    if wrong:
        shown = ", ".join(f"{f:g}" for f in wrong[:5])
        warnings.append(
            f"{name}: focal_len {shown} mm is not a plausible 35 mm equivalent "
            f"({low:g}-{high:g} mm); ignored"
        )
    focals = [f for f in focals if low <= f <= high]
    if not focals:
        return None
    if max(focals) / min(focals) > _ZOOM_RATIO:
        warnings.append(
            f"{name}: focal_len changes during the recording ({min(focals):g}-"
            f"{max(focals):g} mm, a zoom); not used for the camera model"
        )
        return None
    return float(np.median(focals))
