"""Turn significant change into landslide polygons (GeoJSON, RFC 7946).

Loss and gain are grouped together, since a landslide is depletion and deposition side by
side. Cleaning, in pixels: an opening removes speckle (isolated noise pixels above the
LoD), a closing bridges small gaps, then 8-connected regions smaller than `min_area_m2`
are dropped. Polygons follow pixel edges in the metric CRS, where area_m2 is measured;
they are then written in WGS84 lon/lat.

Per region: volume_loss_m3 / volume_gain_m3 sum |dh| times the pixel area over the
region's significant loss / gain pixels; max_abs_dh_m is the largest |dh| in the region.

score (0-1) is a confidence: magnitude * size, where
magnitude = 1 - exp(-(m / LoD - 1)) with m the mean |dh| of the region's significant
pixels (0 at the LoD, 0.86 at 3 LoD), and size = 1 - exp(-area / (2 * min_area_m2))
(0.39 at the minimum area, 0.86 at 4 times it).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.features
import shapely
from scipy import ndimage
from shapely.geometry import shape as to_shape

from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.difference import GAIN, LOSS
from worker.pipeline.errors import InputError
from worker.pipeline.geo import crs_to_string, to_wgs84_geojson
from worker.pipeline.progress import ProgressFn, no_progress
from worker.pipeline.raster_io import read_elevation

METHODS = ("threshold",)


@dataclass
class VectorizeOptions:
    min_area_m2: float = 25.0
    opening_px: int = 1  # radius of the square that removes speckle
    closing_px: int = 2  # radius of the square that bridges gaps


@dataclass
class VectorizeResult:
    detections: int
    total_area_m2: float
    total_volume_loss_m3: float
    total_volume_gain_m3: float
    method: str
    crs: str  # the metric CRS where areas and volumes were measured
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def vectorize(
    dh_path: Path,
    significance_path: Path,
    out_geojson: Path,
    options: VectorizeOptions | None = None,
    method: str = "threshold",
    progress: ProgressFn = no_progress,
) -> VectorizeResult:
    """Write the detections as a FeatureCollection to `out_geojson` (atomically)."""
    options = options or VectorizeOptions()
    if method not in METHODS:
        raise InputError(f"unknown detection method {method!r}; available: {', '.join(METHODS)}")
    start = time.perf_counter()
    dh, profile = read_elevation(dh_path)
    with rasterio.open(significance_path) as src:
        significance = src.read(1)
        tags = src.tags()
    if significance.shape != dh.shape:
        raise InputError("the significance mask is not on the grid of the elevation difference")
    lod = _lod(tags, significance, dh)
    transform, crs = profile["transform"], profile["crs"]
    pixel_area = abs(transform.a * transform.e)

    regions = _regions(significance, options)
    progress(0.4)
    labels, count = ndimage.label(regions, structure=np.ones((3, 3), dtype=bool))
    features = []
    if count:
        sizes = np.bincount(labels.ravel(), minlength=count + 1)
        keep = np.flatnonzero(sizes * pixel_area >= options.min_area_m2)
        keep = keep[keep > 0]
        objects = ndimage.find_objects(labels)
        for label in keep:
            window = objects[label - 1]
            features.append(
                _feature(
                    label,
                    labels[window],
                    dh[window],
                    significance[window],
                    rasterio.windows.transform(_to_window(window), transform),
                    crs,
                    pixel_area,
                    lod,
                    options,
                    method,
                )
            )
    progress(0.9)
    features.sort(key=lambda f: (-f["properties"]["area_m2"], f["bbox"]))
    features = [{"id": number, **feature} for number, feature in enumerate(features, start=1)]
    collection = {
        "type": "FeatureCollection",
        "features": features,
        "metric_crs": crs_to_string(crs),  # foreign member: where area_m2 was measured
    }
    write_text_atomic(Path(out_geojson), json.dumps(collection, separators=(",", ":")))
    progress(1.0)
    props = [f["properties"] for f in features]
    return VectorizeResult(
        detections=len(features),
        total_area_m2=float(sum(p["area_m2"] for p in props)),
        total_volume_loss_m3=float(sum(p["volume_loss_m3"] for p in props)),
        total_volume_gain_m3=float(sum(p["volume_gain_m3"] for p in props)),
        method=method,
        crs=crs_to_string(crs),
        seconds=time.perf_counter() - start,
    )


def _regions(significance: np.ndarray, options: VectorizeOptions) -> np.ndarray:
    changed = (significance == LOSS) | (significance == GAIN)
    if options.opening_px > 0:
        size = 2 * options.opening_px + 1
        changed = ndimage.binary_opening(changed, structure=np.ones((size, size), dtype=bool))
    if options.closing_px > 0:
        size = 2 * options.closing_px + 1
        # Pad so the closing does not erode regions that touch the raster edge.
        padded = np.pad(changed, options.closing_px, mode="edge")
        closed = ndimage.binary_closing(padded, structure=np.ones((size, size), dtype=bool))
        changed = closed[tuple(slice(options.closing_px, -options.closing_px) for _ in range(2))]
    return changed


def _to_window(slices: tuple[slice, slice]) -> rasterio.windows.Window:
    rows, cols = slices
    return rasterio.windows.Window(
        cols.start, rows.start, cols.stop - cols.start, rows.stop - rows.start
    )


def _feature(
    label: int,
    labels: np.ndarray,
    dh: np.ndarray,
    significance: np.ndarray,
    transform: rasterio.Affine,
    crs: rasterio.crs.CRS,
    pixel_area: float,
    lod: float | None,
    options: VectorizeOptions,
    method: str,
) -> dict[str, Any]:
    inside = labels == label
    polygons = [
        to_shape(geom)
        for geom, value in rasterio.features.shapes(
            inside.astype(np.uint8), mask=inside, transform=transform, connectivity=8
        )
        if value == 1
    ]
    geometry = shapely.union_all(polygons) if len(polygons) > 1 else polygons[0]
    loss = inside & (significance == LOSS)
    gain = inside & (significance == GAIN)
    significant = loss | gain
    abs_dh = np.abs(dh[inside & np.isfinite(dh)])
    area = float(geometry.area)
    volume_loss = float(-dh[loss].sum() * pixel_area)
    volume_gain = float(dh[gain].sum() * pixel_area)
    mean_abs = float(np.abs(dh[significant]).mean()) if significant.any() else 0.0
    geojson = to_wgs84_geojson(geometry, crs)
    lons_lats = shapely.get_coordinates(to_shape(geojson))
    return {
        "type": "Feature",
        "bbox": [round(float(v), 7) for v in (*lons_lats.min(axis=0), *lons_lats.max(axis=0))],
        "geometry": geojson,
        "properties": {
            "area_m2": round(area, 2),
            "volume_loss_m3": round(volume_loss, 2),
            "volume_gain_m3": round(volume_gain, 2),
            "max_abs_dh_m": round(float(abs_dh.max()) if abs_dh.size else 0.0, 3),
            "score": round(_score(mean_abs, area, lod, options), 3),
            "method": method,
        },
    }


def _score(
    mean_abs_dh: float, area_m2: float, lod: float | None, options: VectorizeOptions
) -> float:
    magnitude = 1.0 - math.exp(-(mean_abs_dh / lod - 1.0)) if lod else 1.0
    size = 1.0 - math.exp(-area_m2 / (2.0 * max(options.min_area_m2, 1e-9)))
    return max(0.0, min(1.0, magnitude)) * size


def _lod(tags: dict[str, str], significance: np.ndarray, dh: np.ndarray) -> float | None:
    """The LoD the difference stage wrote, else the smallest significant |dh|."""
    if tags.get("LOD_M"):
        return float(tags["LOD_M"])
    significant = (significance == LOSS) | (significance == GAIN)
    if not significant.any():
        return None
    return float(np.nanmin(np.abs(dh[significant])))
