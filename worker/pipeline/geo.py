"""Coordinate systems, geometry output and raster I/O shared by the comparison stages.

Rules kept in one place:
- UTM zone choice: the zone of the centroid longitude, zone = floor((lon + 180) / 6) + 1
  (clamped to 1..60), EPSG 326zz when the centroid latitude is >= 0, else 327zz. The
  Norway/Svalbard exceptions are deliberately not applied: one simple rule everywhere.
- Output geometries (GeoJSON, RFC 7946): WGS84 lon/lat, exterior rings counter-clockwise,
  holes clockwise, coordinates rounded to 7 decimals (about 1 cm).
- Elevation rasters: float32, nodata written as -9999 in files, NaN in memory.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.warp
import shapely
from pyproj import CRS, Geod, Transformer
from rasterio.crs import CRS as RioCRS
from rasterio.enums import Resampling
from rasterio.transform import Affine
from shapely.geometry import mapping
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient

from worker.pipeline.atomic import atomic_path

NODATA = -9999.0
MASK_NODATA = 255
COORDINATE_DECIMALS = 7
_WGS84 = CRS.from_epsg(4326)
_GEOD = Geod(ellps="WGS84")
# A resampled pixel counts as valid only when (nearly) all of its bilinear weight comes
# from valid source pixels, so nodata never bleeds into elevations.
_MIN_VALID_WEIGHT = 0.999


def utm_epsg_for_lonlat(lon: float, lat: float) -> int:
    """EPSG code of the UTM zone containing (lon, lat), by the rule in the module doc."""
    zone = min(max(math.floor((lon + 180.0) / 6.0) + 1, 1), 60)
    return (32600 if lat >= 0 else 32700) + zone


def utm_crs_for_lonlat(lon: float, lat: float) -> CRS:
    """The UTM CRS of the zone containing (lon, lat)."""
    return CRS.from_epsg(utm_epsg_for_lonlat(lon, lat))


def crs_to_string(crs: RioCRS | CRS) -> str:
    """'EPSG:xxxx' when the CRS has an EPSG code, else its WKT."""
    epsg = crs.to_epsg()
    return f"EPSG:{epsg}" if epsg else crs.to_wkt()


def is_metric_projected(crs: RioCRS | CRS) -> bool:
    """True for a projected CRS whose horizontal unit is the metre."""
    pcrs = CRS.from_user_input(crs)
    if not pcrs.is_projected:
        return False
    return all(axis.unit_name in ("metre", "meter") for axis in pcrs.axis_info[:2])


def transformer_to_wgs84(crs: RioCRS | CRS) -> Transformer:
    return Transformer.from_crs(CRS.from_user_input(crs), _WGS84, always_xy=True)


def to_wgs84_geojson(geom: BaseGeometry, crs: RioCRS | CRS) -> dict[str, Any]:
    """GeoJSON geometry dict of `geom` (in `crs`) in WGS84 lon/lat, RFC 7946 oriented."""
    transformer = transformer_to_wgs84(crs)
    lonlat = shapely.transform(geom, lambda xy: np.column_stack(transformer.transform(*xy.T)))
    return geojson_rfc7946(lonlat)


def geojson_rfc7946(geom: BaseGeometry) -> dict[str, Any]:
    """GeoJSON dict with CCW exterior rings, CW holes, coordinates rounded."""
    rounded = shapely.transform(geom, lambda xy: np.round(xy, COORDINATE_DECIMALS))
    return _as_plain(mapping(_orient_ccw(rounded)))


def _orient_ccw(geom: BaseGeometry) -> BaseGeometry:
    if geom.geom_type == "Polygon":
        return orient(geom, sign=1.0)
    if geom.geom_type == "MultiPolygon":
        return shapely.MultiPolygon([orient(p, sign=1.0) for p in geom.geoms])
    return geom


def _as_plain(obj: Any) -> Any:
    """Turn shapely's nested tuples into lists so the dict is plain JSON."""
    if isinstance(obj, dict):
        return {k: _as_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_as_plain(v) for v in obj]
    if isinstance(obj, np.floating):
        return float(obj)
    return obj


def densified_bounds_polygon(bounds: tuple[float, float, float, float],
                             points_per_edge: int = 21) -> shapely.Polygon:
    """Rectangle of `bounds` with extra vertices so it bends correctly when reprojected."""
    left, bottom, right, top = bounds
    t = np.linspace(0.0, 1.0, points_per_edge)[:-1]
    xs = np.concatenate([left + (right - left) * t, np.full_like(t, right),
                         right - (right - left) * t, np.full_like(t, left)])
    ys = np.concatenate([np.full_like(t, bottom), bottom + (top - bottom) * t,
                         np.full_like(t, top), top - (top - bottom) * t])
    return shapely.Polygon(np.column_stack([xs, ys]))


def pixel_size_m(
    transform: Affine, crs: RioCRS | CRS, shape: tuple[int, int]
) -> tuple[float, float]:
    """Pixel size (x, y) in metres; for a geographic CRS, geodesic at the raster centre."""
    res_x, res_y = abs(transform.a), abs(transform.e)
    pcrs = CRS.from_user_input(crs)
    if pcrs.is_geographic:
        cx, cy = transform @ (shape[1] / 2, shape[0] / 2)
        _, _, dx = _GEOD.inv(cx - res_x / 2, cy, cx + res_x / 2, cy)
        _, _, dy = _GEOD.inv(cx, cy - res_y / 2, cx, cy + res_y / 2)
        return float(dx), float(dy)
    factor = pcrs.axis_info[0].unit_conversion_factor if pcrs.axis_info else 1.0
    return res_x * factor, res_y * factor


def read_elevation(path: Path, window: Any = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Band 1 as float32 with NaN for nodata (and for NaN/inf values), plus the profile."""
    with rasterio.open(path) as src:
        data = src.read(1, window=window, masked=True)
        profile = dict(src.profile)
        if window is not None:
            profile["transform"] = src.window_transform(window)
            profile["height"], profile["width"] = data.shape
    array = np.ma.filled(data.astype(np.float32), np.nan)
    array[~np.isfinite(array)] = np.nan
    return array, profile


def write_geotiff(path: Path, array: np.ndarray, transform: Affine, crs: RioCRS | CRS | str,
                  nodata: float | None = None, tags: dict[str, str] | None = None) -> None:
    """Write one band atomically as a tiled, deflate-compressed GeoTIFF.

    Float arrays are written as float32 with NaN replaced by -9999 (the declared nodata);
    uint8 arrays are written as they are with nodata 255 unless told otherwise.
    """
    if array.dtype == np.uint8:
        data = array
        nodata = MASK_NODATA if nodata is None else nodata
        predictor = 2
    else:
        data = np.where(np.isfinite(array), array, NODATA).astype(np.float32)
        nodata = NODATA if nodata is None else nodata
        predictor = 3
    height, width = data.shape
    profile = {
        "driver": "GTiff",
        "height": height,
        "width": width,
        "count": 1,
        "dtype": data.dtype.name,
        "crs": RioCRS.from_user_input(crs),
        "transform": transform,
        "nodata": nodata,
        "compress": "deflate",
        "predictor": predictor,
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
    }
    with atomic_path(Path(path)) as tmp, rasterio.open(tmp, "w", **profile) as dst:
        dst.write(data, 1)
        if tags:
            dst.update_tags(**tags)


def warp_elevation(
    array: np.ndarray,
    src_transform: Affine,
    src_crs: RioCRS | CRS,
    dst_transform: Affine,
    dst_crs: RioCRS | CRS,
    dst_shape: tuple[int, int],
    num_threads: int = 2,
) -> np.ndarray:
    """Bilinear resampling of an elevation array (NaN = nodata) onto a destination grid.

    A destination pixel is valid only if all source pixels that contribute to it are
    valid, so nodata never blends into elevations (holes grow by at most one pixel).
    """
    valid = np.isfinite(array)
    src = np.where(valid, array, NODATA).astype(np.float32)
    out = np.full(dst_shape, NODATA, dtype=np.float32)
    weight = np.zeros(dst_shape, dtype=np.float32)
    common = {
        "src_transform": src_transform,
        "src_crs": src_crs,
        "dst_transform": dst_transform,
        "dst_crs": dst_crs,
        "resampling": Resampling.bilinear,
        "num_threads": num_threads,
        "tolerance": 0.0,
    }
    rasterio.warp.reproject(src, out, src_nodata=NODATA, dst_nodata=NODATA, **common)
    rasterio.warp.reproject(valid.astype(np.float32), weight, dst_nodata=0.0, **common)
    out[(weight < _MIN_VALID_WEIGHT) | (out == NODATA)] = np.nan
    return out


def footprint_lonlat(bounds: tuple[float, float, float, float], crs: RioCRS | CRS
                     ) -> shapely.Polygon:
    """The raster extent as a lon/lat polygon (densified edges, not rounded)."""
    transformer = transformer_to_wgs84(crs)
    poly = densified_bounds_polygon(bounds)
    return shapely.transform(poly, lambda xy: np.column_stack(transformer.transform(*xy.T)))
