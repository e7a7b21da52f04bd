"""The site map of a report: hillshade of the post DSM, Δh on top, landslides outlined."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import rasterio
import shapely
from matplotlib.colors import TwoSlopeNorm
from pyproj import Transformer
from rasterio.enums import Resampling
from shapely.geometry import shape

from worker.pipeline.atomic import atomic_path
from worker.reports.data import DetectionRow
from worker.reports.fonts import matplotlib_families
from worker.reports.i18n import Catalogue, catalogue

MAX_PIXELS = 1200


def _read(path: Path) -> tuple[np.ndarray, tuple[float, float, float, float], float, object]:
    """Band 1 (NaN for nodata) decimated to at most MAX_PIXELS a side, extent, pixel size."""
    with rasterio.open(path) as src:
        scale = max(1.0, max(src.width, src.height) / MAX_PIXELS)
        shape_ = (max(1, round(src.height / scale)), max(1, round(src.width / scale)))
        data = src.read(1, out_shape=shape_, masked=True, resampling=Resampling.average)
        left, bottom, right, top = src.bounds
        pixel = abs(src.transform.a) * src.width / shape_[1]
        crs = src.crs
    array = np.ma.filled(data.astype("float64"), np.nan)
    return array, (left, right, bottom, top), pixel, crs


def hillshade(dsm: np.ndarray, pixel_m: float, azimuth: float = 315, altitude: float = 45):
    """Shaded relief in 0..1 of an elevation array in metres (NaN stays NaN)."""
    dy, dx = np.gradient(dsm, pixel_m)
    slope = np.pi / 2 - np.arctan(np.hypot(dx, dy))
    aspect = np.arctan2(-dx, dy)
    az, alt = np.radians(360 - azimuth + 90), np.radians(altitude)
    shaded = np.sin(alt) * np.sin(slope) + np.cos(alt) * np.cos(slope) * np.cos(az - aspect)
    return np.clip(shaded, 0, 1)


def site_map(
    dh_path: Path,
    dsm_path: Path,
    detections: list[DetectionRow],
    out_png: Path,
    title: str,
    dpi: int = 150,
    words: Catalogue | None = None,
) -> Path:
    """Write the map as a PNG (atomically), its labels in `words`' language (default
    English); return its path."""
    words = words or catalogue()
    dh, dh_extent, _pixel, crs = _read(dh_path)
    dsm, dsm_extent, dsm_pixel, _ = _read(dsm_path)
    limit = float(np.nanpercentile(np.abs(dh), 99)) if np.isfinite(dh).any() else 1.0
    limit = max(limit, 0.1)

    plt.rcParams["font.family"] = matplotlib_families()
    fig, ax = plt.subplots(figsize=(7.2, 5.6), dpi=dpi)
    ax.imshow(hillshade(dsm, dsm_pixel), cmap="gray", extent=dsm_extent, vmin=0, vmax=1)
    shown = np.ma.masked_where(~np.isfinite(dh) | (np.abs(dh) < 0.15 * limit), dh)
    image = ax.imshow(
        shown,
        cmap="RdBu_r",
        norm=TwoSlopeNorm(vcenter=0.0, vmin=-limit, vmax=limit),
        extent=dh_extent,
        alpha=0.75,
        interpolation="nearest",
    )
    to_map = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform
    for row in detections:
        outline = shapely.transform(
            shape(row.geometry), lambda xy: np.column_stack(to_map(xy[:, 0], xy[:, 1]))
        )
        polygons = getattr(outline, "geoms", [outline])
        for polygon in polygons:
            x, y = polygon.exterior.xy
            ax.plot(x, y, color="black", linewidth=1.4)
            ax.plot(x, y, color="yellow", linewidth=0.7)
        point = outline.representative_point()
        ax.annotate(
            str(row.number),
            (point.x, point.y),
            color="black",
            fontsize=9,
            fontweight="bold",
            fontfamily="DejaVu Sans",  # digits only; the Japanese font has no bold
            ha="center",
            va="center",
            bbox={"boxstyle": "circle,pad=0.2", "fc": "yellow", "ec": "black", "lw": 0.6},
        )
    ax.set_xlim(dh_extent[0], dh_extent[1])
    ax.set_ylim(dh_extent[2], dh_extent[3])
    crs_name = crs.to_string() if crs else words.text("map.unknown_crs")
    ax.set_xlabel(words.text("map.easting", crs=crs_name))
    ax.set_ylabel(words.text("map.northing"))
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    ax.set_title(title, fontsize=10)
    bar = fig.colorbar(image, ax=ax, shrink=0.8, pad=0.02)
    bar.set_label(words.text("map.dh"))
    fig.tight_layout()
    with atomic_path(Path(out_png)) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    plt.close(fig)
    return Path(out_png)
