"""Areas of interest as users send them: GeoJSON (Multi)Polygons in lon/lat, checked whole.

A site's area of interest is served to everyone (OGC API – Features, the map, reports),
so one that is not GeoJSON must be refused when it is sent, with what is wrong with it,
rather than break those pages later.
"""

from __future__ import annotations

import math
from typing import Any

from shapely.geometry import shape
from shapely.validation import explain_validity

AREA_TYPES = ("Polygon", "MultiPolygon")
# More vertices than any drawn or digitised outline of a slope needs.
MAX_POSITIONS = 100_000


class BadGeoJson(ValueError):
    """The value is not a usable area of interest; the message says what is wrong."""


def check_area_of_interest(value: dict[str, Any]) -> dict[str, Any]:
    """`value` if it is a valid GeoJSON Polygon or MultiPolygon in WGS84 lon/lat."""
    kind = value.get("type")
    if kind not in AREA_TYPES:
        raise BadGeoJson(
            f"an area of interest must be a GeoJSON Polygon or MultiPolygon, not {kind!r}"
        )
    coordinates = value.get("coordinates")
    polygons = [coordinates] if kind == "Polygon" else coordinates
    if not isinstance(polygons, list) or not polygons:
        raise BadGeoJson(f"a {kind}'s coordinates must be a non-empty list")
    positions = 0
    for polygon in polygons:
        positions += _check_polygon(polygon)
        if positions > MAX_POSITIONS:
            raise BadGeoJson(f"an area of interest may have at most {MAX_POSITIONS} positions")
    geometry = shape({"type": kind, "coordinates": coordinates})
    if not geometry.is_valid:
        raise BadGeoJson(
            f"the area of interest is not a valid {kind}: {explain_validity(geometry)}"
        )
    return {"type": kind, "coordinates": coordinates}


def is_area_of_interest(value: Any) -> bool:
    """Whether a stored value is a usable area of interest (rows older than the check)."""
    try:
        check_area_of_interest(value)
    except (BadGeoJson, AttributeError):
        return False
    return True


def _check_polygon(rings: Any) -> int:
    if not isinstance(rings, list) or not rings:
        raise BadGeoJson("a polygon must be a non-empty list of linear rings")
    count = 0
    for ring in rings:
        if not isinstance(ring, list) or len(ring) < 4:
            raise BadGeoJson("each ring of a polygon must be a list of at least 4 positions")
        for position in ring:
            _check_position(position)
        if ring[0] != ring[-1]:
            raise BadGeoJson("each ring of a polygon must end at the position it starts at")
        count += len(ring)
    return count


def _check_position(position: Any) -> None:
    if not isinstance(position, list) or len(position) not in (2, 3):
        raise BadGeoJson(f"a position must be [longitude, latitude], not {position!r:.80}")
    if not all(
        isinstance(n, int | float) and not isinstance(n, bool) and math.isfinite(n)
        for n in position
    ):
        raise BadGeoJson(f"a position must hold finite numbers, not {position!r:.80}")
    lon, lat = position[0], position[1]
    if not (-180 <= lon <= 180 and -90 <= lat <= 90):
        raise BadGeoJson(
            f"position {position!r:.80} is not a WGS84 longitude, latitude (-180..180, -90..90)"
        )
