"""Measurements a field team makes on the map: an elevation profile along a line through
one or more DSMs, and the volume between pre and post inside a polygon.

Geometries come as GeoJSON in WGS84 longitude/latitude (what a web map draws) and are
carried into each raster's own CRS. Reads are windowed to the geometry's bounds and
bounded in size, so a measurement costs what its geometry covers, never the whole DSM.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import shapely
from pyproj import Transformer
from rasterio.features import geometry_mask
from rasterio.windows import Window, from_bounds
from shapely.geometry import LineString, Polygon, shape

from worker.pipeline.errors import InputError

MAX_PROFILE_SAMPLES = 2000
MAX_VOLUME_CELLS = 25_000_000  # 100 MB of float32 per raster read


def _geometry(geojson: dict[str, Any], kind: str) -> Any:
    try:
        geometry = shape(geojson)
    except Exception as exc:  # shapely raises several types for malformed GeoJSON
        raise InputError(f"the {kind} is not valid GeoJSON: {exc}") from None
    return geometry


def _to_crs(geometry: Any, crs: Any) -> Any:
    to = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    return shapely.transform(geometry, lambda xy: np.column_stack(to.transform(xy[:, 0], xy[:, 1])))


@dataclass
class Profile:
    distance_m: list[float]
    # per raster name: heights along the line (None where it has no value)
    heights_m: dict[str, list[float | None]]
    length_m: float
    step_m: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def elevation_profile(
    line: dict[str, Any], rasters: dict[str, Path], samples: int = 400
) -> Profile:
    """Heights of each raster along `line` (a GeoJSON LineString, WGS84), at `samples`
    evenly spaced points (bilinear between cells; None outside a raster or in its
    nodata). Distances are measured in the first raster's CRS (metres in a UTM zone)."""
    geometry = _geometry(line, "line")
    if not isinstance(geometry, LineString) or geometry.length == 0:
        raise InputError("the profile needs a LineString of at least two distinct points")
    if not rasters:
        raise InputError("there is no DSM to draw a profile of")
    samples = int(min(max(samples, 2), MAX_PROFILE_SAMPLES))
    first = next(iter(rasters.values()))
    with rasterio.open(first) as src:
        crs = src.crs
    projected = _to_crs(geometry, crs)
    length = float(projected.length)
    distances = np.linspace(0.0, length, samples)
    points = [projected.interpolate(d) for d in distances]
    xy = np.array([(p.x, p.y) for p in points])
    heights = {name: _sample_bilinear(path, xy, crs) for name, path in rasters.items()}
    return Profile(
        distance_m=[round(float(d), 3) for d in distances],
        heights_m=heights,
        length_m=round(length, 3),
        step_m=round(length / (samples - 1), 4),
    )


def _sample_bilinear(path: Path, xy: np.ndarray, crs: Any) -> list[float | None]:
    with rasterio.open(path) as src:
        if src.crs != crs:
            to = Transformer.from_crs(crs, src.crs, always_xy=True)
            xs, ys = to.transform(xy[:, 0], xy[:, 1])
            xy = np.column_stack([xs, ys])
        inv = ~src.transform
        cols, rows = inv * (xy[:, 0], xy[:, 1])
        cols, rows = np.asarray(cols) - 0.5, np.asarray(rows) - 0.5  # cell centres
        c0 = max(0, int(np.floor(cols.min())))
        r0 = max(0, int(np.floor(rows.min())))
        c1 = min(src.width, int(np.floor(cols.max())) + 2)
        r1 = min(src.height, int(np.floor(rows.max())) + 2)
        out: list[float | None] = [None] * len(xy)
        if c1 <= c0 or r1 <= r0:
            return out
        if (c1 - c0) * (r1 - r0) > MAX_VOLUME_CELLS:
            raise InputError("the line crosses too large a part of the DSM at once")
        z = src.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True)
        z = z.astype(np.float64).filled(np.nan)
    for i, (c, r) in enumerate(zip(cols - c0, rows - r0, strict=True)):
        ic, ir = math.floor(c), math.floor(r)
        fc, fr = c - ic, r - ir
        if ic < 0 or ir < 0 or ic + 1 >= z.shape[1] or ir + 1 >= z.shape[0]:
            continue
        block = z[ir : ir + 2, ic : ic + 2]
        weights = np.array([[(1 - fr) * (1 - fc), (1 - fr) * fc], [fr * (1 - fc), fr * fc]])
        good = np.isfinite(block)
        if not good.any():
            continue
        value = float((block[good] * weights[good]).sum() / weights[good].sum())
        out[i] = round(value, 3)
    return out


@dataclass
class Volume:
    area_m2: float  # of the polygon
    measured_m2: float  # of its cells with a Δh
    cut_m3: float  # material lost (post below pre), positive
    fill_m3: float  # material gained
    net_m3: float  # fill − cut
    # Only the cells whose |Δh| exceeds their LoD (the change that is not noise)
    cut_beyond_lod_m3: float
    fill_beyond_lod_m3: float
    lod_m: float | None  # median LoD inside the polygon
    cells: int

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def polygon_volume(
    polygon: dict[str, Any], dh_path: Path, lod: Path | float | None = None
) -> Volume:
    """Cut, fill and net volume of Δh = post − pre inside `polygon` (a GeoJSON Polygon,
    WGS84), with the part beyond the level of detection: a per-cell LoD raster on the Δh
    grid, one LoD for all cells, or None (then every cell counts as beyond it)."""
    geometry = _geometry(polygon, "polygon")
    if not isinstance(geometry, Polygon) or geometry.area == 0:
        raise InputError("the volume needs a Polygon with an area")
    with rasterio.open(dh_path) as src:
        shape_m = _to_crs(geometry, src.crs)
        if not shape_m.is_valid:
            raise InputError("the polygon crosses itself; draw it again without crossings")
        window = from_bounds(*shape_m.bounds, transform=src.transform)
        window = window.round_offsets(op="floor").round_lengths(op="ceil")
        window = (
            window.intersection(Window(0, 0, src.width, src.height))
            if _overlaps(window, src)
            else None
        )
        if window is None:
            raise InputError("the polygon lies outside the comparison's Δh")
        if window.width * window.height > MAX_VOLUME_CELLS:
            raise InputError(
                f"the polygon covers {int(window.width * window.height)} cells; at most "
                f"{MAX_VOLUME_CELLS} are measured at once"
            )
        dh = src.read(1, window=window, masked=True).astype(np.float64).filled(np.nan)
        transform = src.window_transform(window)
        cell = abs(src.res[0] * src.res[1])
    inside = ~geometry_mask([shape_m], out_shape=dh.shape, transform=transform)
    if isinstance(lod, Path):
        with rasterio.open(lod) as src:
            lod_grid = src.read(1, window=window, masked=True).astype(np.float64).filled(np.nan)
    else:
        lod_grid = np.full(dh.shape, np.nan if lod is None else float(lod))
    valid = inside & np.isfinite(dh)
    values = dh[valid]
    lods = lod_grid[valid]
    beyond = np.abs(values) > np.where(np.isfinite(lods), lods, 0.0)
    cut = float(-values[values < 0].sum() * cell)
    fill = float(values[values > 0].sum() * cell)
    finite_lods = lods[np.isfinite(lods)]
    return Volume(
        area_m2=round(float(shape_m.area), 2),
        measured_m2=round(float(valid.sum() * cell), 2),
        cut_m3=round(cut, 2),
        fill_m3=round(fill, 2),
        net_m3=round(fill - cut, 2),
        cut_beyond_lod_m3=round(float(-values[beyond & (values < 0)].sum() * cell), 2),
        fill_beyond_lod_m3=round(float(values[beyond & (values > 0)].sum() * cell), 2),
        lod_m=round(float(np.median(finite_lods)), 3) if finite_lods.size else None,
        cells=int(valid.sum()),
    )


def _overlaps(window: Window, src: rasterio.io.DatasetReader) -> bool:
    return (
        window.col_off < src.width
        and window.row_off < src.height
        and window.col_off + window.width > 0
        and window.row_off + window.height > 0
    )


def heights_at(lon: float, lat: float, rasters: dict[str, Path]) -> dict[str, float | None]:
    """Each raster's value at one WGS84 point (bilinear between cells; None outside it or
    in its nodata): what the map shows under the cursor."""
    out: dict[str, float | None] = {}
    for name, path in rasters.items():
        with rasterio.open(path) as src:
            crs = src.crs
        to = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        x, y = to.transform(lon, lat)
        out[name] = _sample_bilinear(path, np.array([[x, y]]), crs)[0]
    return out
