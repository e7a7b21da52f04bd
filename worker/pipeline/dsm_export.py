"""DSM export as the paper does it: grid the point cloud, fill gaps by Fast Marching.

1. Grid: every DSM pixel is a square cell of `resolution_m` in the points' metric CRS;
   its value is the mean height of the points that fall into it (`statistic="median"`
   is the robust option, for clouds with residual outliers).
2. Fill: cells without points inside the survey footprint are filled by Telea's Fast
   Marching inpainting (`cv2.inpaint`, `INPAINT_TELEA`). The footprint is the set of
   cells with points, closed over gaps up to `max_gap_m` and with interior holes
   filled; nothing is extrapolated beyond it. A mask keeps which cells were filled.
3. Write: a Cloud-Optimized GeoTIFF (float32, nodata -9999, CRS, deflate with the
   floating-point predictor, averaged overviews), the filled-cells mask as a COG
   (uint8: 0 measured, 1 filled, 255 outside), and on request the paper's grey-scale
   PNG: 8-bit, one intensity level per `png_m_per_level` metres (the paper: 2 cm pixels
   and 1.2 cm per level, so 256 levels span 3.07 m) above `png_base_m` (default: the
   lowest DSM value); values beyond the span saturate; nodata is 0 and the lowest
   valid level is 1.

The grid is snapped to whole multiples of the resolution, so DSMs of the same site from
different surveys share their cell edges.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pyproj import CRS
from rasterio.transform import Affine

from worker.pipeline.atomic import atomic_path
from worker.pipeline.cog import RasterRole, write_cog
from worker.pipeline.errors import InputError
from worker.pipeline.geo import crs_to_string, is_metric_projected
from worker.pipeline.raster_io import write_geotiff

STATISTICS = ("mean", "median")
FILLED_MEASURED, FILLED_INPAINTED, FILLED_OUTSIDE = 0, 1, 255
MAX_CELLS = 80_000_000


@dataclass
class DsmOptions:
    resolution_m: float | None = None  # None: twice the median point spacing, snapped
    statistic: str = "mean"
    inpaint: bool = True
    inpaint_radius_px: int = 3
    max_gap_m: float | None = None  # None: 10 cells
    bounds: tuple[float, float, float, float] | None = None  # left, bottom, right, top
    png: bool = False
    png_m_per_level: float = 0.012
    png_base_m: float | None = None


@dataclass
class DsmGrid:
    """The gridded DSM before and after filling, on a north-up grid."""

    values: np.ndarray  # (rows, cols) float32, NaN = no data
    counts: np.ndarray  # points per cell
    transform: Affine
    filled: np.ndarray | None = None  # (rows, cols) uint8, FILLED_* codes

    @property
    def resolution_m(self) -> float:
        return float(self.transform.a)


@dataclass
class DsmResult:
    dsm_path: str
    filled_mask_path: str
    png_path: str | None
    crs: str
    resolution_m: float
    width: int
    height: int
    bounds: tuple[float, float, float, float]
    points: int
    completeness: float  # cells with points / cells in the footprint, before filling
    filled_cells: int
    statistic: str
    z_min: float | None
    z_max: float | None
    png_m_per_level: float | None
    png_base_m: float | None
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["bounds"] = list(self.bounds)
        return d


def auto_resolution(points: np.ndarray) -> float:
    """Twice the median nearest-neighbour spacing of a sample, snapped to 1-2-5 steps."""
    xy = points[:, :2]
    if len(xy) < 10:
        raise InputError("too few points to choose a DSM resolution")
    rng = np.random.default_rng(0)
    sample = xy[rng.choice(len(xy), min(len(xy), 20000), replace=False)]
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(xy).query(sample, k=2)
    spacing = float(np.median(dist[:, 1])) * 2.0
    spacing = max(spacing, 1e-3)
    exponent = np.floor(np.log10(spacing))
    for step in (1.0, 2.0, 5.0, 10.0):
        value = step * 10**exponent
        if value >= spacing * 0.999:
            return float(round(value, 6))
    return float(10 ** (exponent + 1))


def grid_points(
    points: np.ndarray,
    resolution_m: float,
    bounds: tuple[float, float, float, float] | None = None,
    statistic: str = "mean",
) -> DsmGrid:
    """Cell values (mean or median height) and counts of points (N, 3) on a snapped grid."""
    if statistic not in STATISTICS:
        raise InputError(f"unknown DSM statistic {statistic!r}; use one of {STATISTICS}")
    points = np.asarray(points, dtype=np.float64)
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        points = points[finite]
    del finite
    if len(points) == 0:
        raise InputError("the point cloud is empty; no DSM can be made")
    res = float(resolution_m)
    x, y = points[:, 0], points[:, 1]
    if bounds is None:
        left = np.floor(x.min() / res) * res
        bottom = np.floor(y.min() / res) * res
        right = (np.floor(x.max() / res) + 1) * res
        top = (np.floor(y.max() / res) + 1) * res
    else:
        left, bottom, right, top = bounds
    cols = round((right - left) / res)
    rows = round((top - bottom) / res)
    if cols <= 0 or rows <= 0:
        raise InputError("the DSM bounds are empty")
    if rows * cols > MAX_CELLS:
        raise InputError(
            f"a DSM of {rows} x {cols} cells at {res} m is too large; choose a coarser resolution"
        )
    # The cell of every point, with as few temporaries of millions of values as can be:
    # fresh memory costs more than the arithmetic.
    c = np.subtract(x, left)
    c /= res
    np.floor(c, out=c)
    r = np.subtract(top, y)
    r /= res
    np.floor(r, out=r)
    z = points[:, 2]
    if c.min() < 0 or c.max() >= cols or r.min() < 0 or r.max() >= rows:
        inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        c, r, z = c[inside], r[inside], z[inside]
    # Whole floats: exact, and one conversion to integers for the lot.
    r *= cols
    r += c
    del c
    cell = r.astype(np.int64)
    del r
    counts = np.bincount(cell, minlength=rows * cols)
    if statistic == "mean":
        sums = np.bincount(cell, weights=z, minlength=rows * cols)
        with np.errstate(invalid="ignore", divide="ignore"):
            values = sums / counts
    else:
        values = np.full(rows * cols, np.nan)
        order = np.lexsort((z, cell))
        cs, zs = cell[order], z[order]
        starts = np.flatnonzero(np.concatenate([[True], cs[1:] != cs[:-1]]))
        n = counts[cs[starts]]
        lo = zs[starts + (n - 1) // 2]
        hi = zs[starts + n // 2]
        values[cs[starts]] = (lo + hi) / 2.0
    values = np.where(counts > 0, values, np.nan).reshape(rows, cols).astype(np.float32)
    transform = Affine(res, 0.0, float(left), 0.0, -res, float(top))
    return DsmGrid(values=values, counts=counts.reshape(rows, cols), transform=transform)


def footprint(has_data: np.ndarray, max_gap_px: int) -> np.ndarray:
    """Cells with data, closed over gaps up to `max_gap_px` wide, interior holes filled."""
    data = has_data.astype(np.uint8)
    closed = data
    if max_gap_px > 0:
        # A (2r+1) square is r iterations of the 3x3 one; padding keeps the closing from
        # growing in from the raster's edge. OpenCV does this ~30x faster than scipy.
        radius = max(1, max_gap_px // 2 + 1)
        kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
        padded = cv2.copyMakeBorder(data, *(radius,) * 4, cv2.BORDER_CONSTANT, value=0)
        grown = cv2.dilate(padded, kernel)
        shrunk = cv2.erode(grown, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        closed = shrunk[radius:-radius, radius:-radius] | data
    # Holes: empty cells that no 4-connected path of empty cells joins to the border.
    canvas = cv2.copyMakeBorder(closed, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    cv2.floodFill(canvas, None, (0, 0), 2, flags=4)
    return canvas[1:-1, 1:-1] != 2


def inpaint(
    grid: DsmGrid, radius_px: int = 3, max_gap_px: int = 10, inside: np.ndarray | None = None
) -> DsmGrid:
    """Fill empty cells inside the footprint (`inside`, computed when not given) by
    Telea's Fast Marching (cv2.inpaint)."""
    values = grid.values
    has_data = np.isfinite(values)
    if inside is None:
        inside = footprint(has_data, max_gap_px)
    holes = inside & ~has_data
    filled = np.full(values.shape, FILLED_OUTSIDE, dtype=np.uint8)
    filled[has_data] = FILLED_MEASURED
    out = values.copy()
    if holes.any():
        # OpenCV's Telea weights assume image-like magnitudes: heights are mapped to
        # 0..65535 (float, so nothing is quantised) and back.
        lo, hi = float(np.nanmin(values)), float(np.nanmax(values))
        scale = 65535.0 / max(hi - lo, 1e-6)
        src = np.where(has_data, (values - lo) * scale, 0.0).astype(np.float32)
        painted = cv2.inpaint(src, holes.astype(np.uint8), radius_px, cv2.INPAINT_TELEA)
        out[holes] = painted[holes].astype(np.float64) / scale + lo
        filled[holes] = FILLED_INPAINTED
    return DsmGrid(values=out, counts=grid.counts, transform=grid.transform, filled=filled)


def grey_png(
    values: np.ndarray, m_per_level: float = 0.012, base_m: float | None = None
) -> tuple[np.ndarray, float]:
    """The paper's grey-scale export: level = 1 + (z - base) / m_per_level, clipped to
    1..255; nodata 0. Returns (uint8 image, base used)."""
    valid = np.isfinite(values)
    if base_m is None:
        base_m = float(np.nanmin(values)) if valid.any() else 0.0
    levels = np.zeros(values.shape, dtype=np.uint8)
    scaled = np.clip(np.round((values[valid] - base_m) / m_per_level) + 1, 1, 255)
    levels[valid] = scaled.astype(np.uint8)
    return levels, base_m


def export_dsm(
    points: np.ndarray,
    crs: str | CRS,
    out_dir: Path,
    options: DsmOptions | None = None,
    name: str = "dsm",
) -> DsmResult:
    """Points (N, 3) in a metric projected CRS -> `name`.tif (COG), `name`_filled.tif
    (COG mask) and, on request, `name`.png in `out_dir` (all written atomically)."""
    start = time.perf_counter()
    options = options or DsmOptions()
    crs = CRS.from_user_input(crs)
    if not is_metric_projected(crs):
        raise InputError(f"DSM points must be in a metric projected CRS, not {crs.name}")
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] < 3:
        raise InputError("points must be an (N, 3) array of x, y, z")
    resolution = options.resolution_m or auto_resolution(points)
    grid = grid_points(points[:, :3], resolution, options.bounds, options.statistic)
    max_gap_px = round(options.max_gap_m / resolution) if options.max_gap_m is not None else 10
    has_data = np.isfinite(grid.values)
    inside = footprint(has_data, max_gap_px)
    completeness = float(has_data.sum() / max(inside.sum(), 1))
    if options.inpaint:
        grid = inpaint(grid, options.inpaint_radius_px, max_gap_px, inside)
    else:
        grid.filled = np.where(has_data, FILLED_MEASURED, FILLED_OUTSIDE).astype(np.uint8)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    dsm_path = out_dir / f"{name}.tif"
    mask_path = out_dir / f"{name}_filled.tif"
    with tempfile.TemporaryDirectory(dir=out_dir, prefix=".dsm-") as tmp:
        plain = Path(tmp) / "dsm.tif"
        write_geotiff(plain, grid.values, grid.transform, crs)
        write_cog(plain, dsm_path, RasterRole.elevation)
        plain_mask = Path(tmp) / "mask.tif"
        write_geotiff(plain_mask, grid.filled, grid.transform, crs, nodata=FILLED_OUTSIDE)
        write_cog(plain_mask, mask_path, RasterRole.mask)
    png_path = None
    base = None
    if options.png:
        image, base = grey_png(grid.values, options.png_m_per_level, options.png_base_m)
        png_path = out_dir / f"{name}.png"
        with atomic_path(png_path) as tmp_png:
            ok, encoded = cv2.imencode(".png", image)
            if not ok:
                raise RuntimeError("PNG encoding failed")
            tmp_png.write_bytes(encoded.tobytes())
    valid = np.isfinite(grid.values)
    rows, cols = grid.values.shape
    t = grid.transform
    return DsmResult(
        dsm_path=str(dsm_path),
        filled_mask_path=str(mask_path),
        png_path=str(png_path) if png_path else None,
        crs=crs_to_string(crs),
        resolution_m=resolution,
        width=cols,
        height=rows,
        bounds=(t.c, t.f - rows * resolution, t.c + cols * resolution, t.f),
        points=len(points),
        completeness=round(completeness, 4),
        filled_cells=int((grid.filled == FILLED_INPAINTED).sum()),
        statistic=options.statistic,
        z_min=float(np.nanmin(grid.values)) if valid.any() else None,
        z_max=float(np.nanmax(grid.values)) if valid.any() else None,
        png_m_per_level=options.png_m_per_level if options.png else None,
        png_base_m=base,
        seconds=round(time.perf_counter() - start, 3),
    )
