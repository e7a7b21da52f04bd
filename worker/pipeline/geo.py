"""Coordinate systems and geometry output shared by the pipeline stages.

Rules kept in one place:
- UTM zone choice: the zone of the centroid longitude, zone = floor((lon + 180) / 6) + 1
  (clamped to 1..60), EPSG 326zz when the centroid latitude is >= 0, else 327zz. The
  Norway/Svalbard exceptions are deliberately not applied: one simple rule everywhere.
- Output geometries (GeoJSON, RFC 7946): WGS84 lon/lat, exterior rings counter-clockwise,
  holes clockwise, coordinates rounded to 7 decimals (about 1 cm).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import shapely
from pyproj import CRS, Geod, Transformer
from rasterio.crs import CRS as RioCRS
from rasterio.transform import Affine
from shapely.geometry import mapping
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient

COORDINATE_DECIMALS = 7
_WGS84 = CRS.from_epsg(4326)
_GEOD = Geod(ellps="WGS84")


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


def densified_bounds_polygon(
    bounds: tuple[float, float, float, float], points_per_edge: int = 21
) -> shapely.Polygon:
    """Rectangle of `bounds` with extra vertices so it bends correctly when reprojected."""
    left, bottom, right, top = bounds
    t = np.linspace(0.0, 1.0, points_per_edge)[:-1]
    xs = np.concatenate(
        [
            left + (right - left) * t,
            np.full_like(t, right),
            right - (right - left) * t,
            np.full_like(t, left),
        ]
    )
    ys = np.concatenate(
        [
            np.full_like(t, bottom),
            bottom + (top - bottom) * t,
            np.full_like(t, top),
            top - (top - bottom) * t,
        ]
    )
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


def footprint_lonlat(
    bounds: tuple[float, float, float, float], crs: RioCRS | CRS
) -> shapely.Polygon:
    """The raster extent as a lon/lat polygon (densified edges, not rounded)."""
    transformer = transformer_to_wgs84(crs)
    poly = densified_bounds_polygon(bounds)
    return shapely.transform(poly, lambda xy: np.column_stack(transformer.transform(*xy.T)))
