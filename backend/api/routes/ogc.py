"""OGC API – Features, Part 1 (core, GeoJSON): what QGIS, ArcGIS Pro and GDAL read.

Collections: `sites`, `surveys` (footprints) and `detections` (landslides of every
comparison). Items take `limit` (1..10000), `offset`, `bbox` (CRS84 lon/lat), `datetime`
(RFC 3339 instant or interval, `..` for an open end) and, beyond the standard, `site_id`
and `comparison_id`. Authentication: `Authorization: Bearer <token>` (or `?api_key=<token>`
for a single request). Links are absolute at SLIDEWATCH_PUBLIC_URL and carry no token:
clients that follow links (GDAL's paging through `next`) send the header with each.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, date, datetime, time, timedelta
from typing import Annotated, Any
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, HTTPException, Query, Request, status
from fastapi.responses import JSONResponse

from backend.api.access import SignedIn
from backend.api.deps import SessionDep, public_base
from backend.db.access import visible_site_ids
from backend.db.models import ApiToken
from backend.ids import RowId, parse_row_id
from backend.services.features import (
    COLLECTIONS,
    Collection,
    FeatureQuery,
    Interval,
    collection_extent,
    get_feature,
    query_features,
)

router = APIRouter(prefix="/ogc", tags=["OGC API – Features"])

MAX_LIMIT = 10000
DEFAULT_LIMIT = 100
GEOJSON = "application/geo+json"
CRS84 = "http://www.opengis.net/def/crs/OGC/1.3/CRS84"
CONFORMANCE = [
    "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/geojson",
    "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/oas30",
]


def _bad(message: str) -> HTTPException:
    return HTTPException(status.HTTP_400_BAD_REQUEST, message)


class Links:
    """Absolute links from the configured public URL (SLIDEWATCH_PUBLIC_URL), never from
    the request's Host (which the client chooses), and never with a token in them: a
    client that sent `api_key` sends it again, or an Authorization header."""

    def __init__(self, request: Request) -> None:
        self.base = public_base(request)

    def href(self, path: str, **params: Any) -> str:
        query = {k: v for k, v in params.items() if v is not None}
        return f"{self.base}{path}" + (f"?{urlencode(query)}" if query else "")

    def link(self, path: str, rel: str, type_: str, title: str | None = None, **params) -> dict:
        out = {"href": self.href(path, **params), "rel": rel, "type": type_}
        if title:
            out["title"] = title
        return out


def _json(body: dict[str, Any], media_type: str = "application/json") -> JSONResponse:
    return JSONResponse(body, media_type=media_type)


def _collection(cid: str) -> Collection:
    try:
        return COLLECTIONS[cid]
    except KeyError:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            f"collection {cid!r} not found; collections: {', '.join(COLLECTIONS)}",
        ) from None


def parse_bbox(value: str | None, bbox_crs: str | None) -> tuple[float, float, float, float] | None:
    if value is None:
        return None
    if bbox_crs not in (None, CRS84):
        raise _bad(f"bbox-crs {bbox_crs!r} is not supported; only {CRS84} (lon/lat)")
    try:
        numbers = [float(v) for v in value.split(",")]
    except ValueError:
        raise _bad(
            f"bbox {value!r} must be 4 numbers: min lon, min lat, max lon, max lat"
        ) from None
    if len(numbers) == 6:  # with heights: drop them
        numbers = [numbers[0], numbers[1], numbers[3], numbers[4]]
    if len(numbers) != 4:
        raise _bad(f"bbox {value!r} must be 4 numbers: min lon, min lat, max lon, max lat")
    min_x, min_y, max_x, max_y = numbers
    if not (-180 <= min_x <= 180 and -180 <= max_x <= 180 and -90 <= min_y <= max_y <= 90):
        raise _bad(f"bbox {value!r} is outside lon -180..180, lat -90..90 or has min > max")
    if min_x > max_x:
        raise _bad(f"bbox {value!r} crosses the antimeridian, which is not supported")
    return min_x, min_y, max_x, max_y


def _parse_moment(text: str, end: bool) -> datetime | None:
    if text in ("..", ""):
        return None
    try:
        if "T" not in text.upper() and len(text) == 10:
            day = date.fromisoformat(text)
            moment = datetime.combine(day, time.min, tzinfo=UTC)
            return moment + timedelta(days=1) - timedelta(microseconds=1) if end else moment
        moment = datetime.fromisoformat(text.replace("z", "Z").replace("Z", "+00:00"))
    except ValueError:
        raise _bad(
            f"datetime {text!r} is not an RFC 3339 date-time (e.g. 2026-06-01T10:00:00Z)"
        ) from None
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def parse_datetime(value: str | None) -> Interval | None:
    if value is None:
        return None
    if "/" in value:
        start_text, _, end_text = value.partition("/")
        start, end = _parse_moment(start_text, False), _parse_moment(end_text, True)
        if start and end and start > end:
            raise _bad(f"datetime interval {value!r} ends before it starts")
        return Interval(start, end)
    if value == "..":
        raise _bad("datetime '..' needs an interval, e.g. '../2026-07-01T00:00:00Z'")
    start, end = _parse_moment(value, False), _parse_moment(value, True)
    return Interval(start, end)


def _int(value: str | None, name: str, default: int, low: int, high: int) -> int:
    if value is None:
        return default
    try:
        number = int(value)
    except ValueError:
        raise _bad(f"{name} {value!r} is not an integer") from None
    if not low <= number <= high:
        raise _bad(f"{name} must be between {low} and {high}, not {number}")
    return number


def items_query(
    limit: Annotated[
        str | None, Query(description=f"Features per page, 1..{MAX_LIMIT} (default 100).")
    ] = None,
    offset: Annotated[str | None, Query(description="Features to skip (paging).")] = None,
    bbox: Annotated[
        str | None, Query(description="min lon,min lat,max lon,max lat (CRS84).")
    ] = None,
    bbox_crs: Annotated[str | None, Query(alias="bbox-crs")] = None,
    datetime_: Annotated[
        str | None,
        Query(
            alias="datetime",
            description="RFC 3339 instant or interval: 2026-06-01T00:00:00Z/.., ../2026-07-01",
        ),
    ] = None,
    site_id: Annotated[RowId | None, Query(description="Only features of this site.")] = None,
    comparison_id: Annotated[
        RowId | None, Query(description="detections: only those of this comparison.")
    ] = None,
) -> FeatureQuery:
    return FeatureQuery(
        limit=_int(limit, "limit", DEFAULT_LIMIT, 1, MAX_LIMIT),
        offset=_int(offset, "offset", 0, 0, 2**31 - 1),
        bbox=parse_bbox(bbox, bbox_crs),
        datetime=parse_datetime(datetime_),
        site_id=site_id,
        comparison_id=comparison_id,
    )


@router.get("", summary="Landing page", include_in_schema=True)
def landing_page(request: Request, _token: SignedIn) -> JSONResponse:
    links = Links(request)
    return _json(
        {
            "title": "slidewatch",
            "description": "Landslides detected from multi-temporal drone surveys: sites, "
            "survey footprints and detections as OGC API – Features.",
            "links": [
                links.link("/ogc", "self", "application/json", "This document"),
                links.link(
                    "/openapi.json",
                    "service-desc",
                    "application/vnd.oai.openapi+json;version=3.0",
                    "The API definition",
                ),
                links.link("/docs", "service-doc", "text/html", "The API documentation"),
                links.link("/ogc/conformance", "conformance", "application/json", "Conformance"),
                links.link("/ogc/collections", "data", "application/json", "Collections"),
            ],
        }
    )


@router.get("/conformance", summary="Conformance classes")
def conformance(_token: SignedIn) -> JSONResponse:
    return _json({"conformsTo": CONFORMANCE})


def _visible(session: SessionDep, token: ApiToken) -> frozenset[int] | None:
    """The sites whose features the token may see (every route here shows only those)."""
    seen = visible_site_ids(session, token)
    return None if seen is None else frozenset(seen)


def _collection_body(
    session: SessionDep, links: Links, collection: Collection, visible: frozenset[int] | None
) -> dict[str, Any]:
    bbox, interval = collection_extent(session, collection.id, visible)
    extent: dict[str, Any] = {
        "spatial": {"bbox": [list(bbox) if bbox else [-180.0, -90.0, 180.0, 90.0]], "crs": CRS84}
    }
    if collection.temporal:
        extent["temporal"] = {
            "interval": [list(interval) if interval else [None, None]],
            "trs": "http://www.opengis.net/def/uom/ISO-8601/0/Gregorian",
        }
    path = f"/ogc/collections/{collection.id}"
    return {
        "id": collection.id,
        "title": collection.title,
        "description": collection.description,
        "itemType": "feature",
        "crs": [CRS84],
        "extent": extent,
        "links": [
            links.link(path, "self", "application/json", collection.title),
            links.link(f"{path}/items", "items", GEOJSON, f"{collection.title} (GeoJSON)"),
        ],
    }


@router.get("/collections", summary="Feature collections")
def collections(request: Request, session: SessionDep, token: SignedIn) -> JSONResponse:
    links = Links(request)
    return _json(
        {
            "links": [links.link("/ogc/collections", "self", "application/json")],
            "collections": [
                _collection_body(session, links, c, _visible(session, token))
                for c in COLLECTIONS.values()
            ],
        }
    )


@router.get("/collections/{collection_id}", summary="A feature collection")
def collection(
    collection_id: str, request: Request, session: SessionDep, token: SignedIn
) -> JSONResponse:
    body = _collection_body(
        session, Links(request), _collection(collection_id), _visible(session, token)
    )
    return _json(body)


@router.get(
    "/collections/{collection_id}/items",
    summary="Features of a collection (GeoJSON), paged through `next` links",
    responses={200: {"content": {GEOJSON: {}}}},
)
def items(
    collection_id: str,
    request: Request,
    session: SessionDep,
    token: SignedIn,
    query: Annotated[FeatureQuery, Depends(items_query)],
) -> JSONResponse:
    _collection(collection_id)
    query = replace(query, visible=_visible(session, token))
    features, matched = query_features(session, collection_id, query)
    links = Links(request)
    path = f"/ogc/collections/{collection_id}/items"
    kept = {
        k: v for k, v in request.query_params.items() if k not in ("offset", "limit", "api_key")
    }
    page = [
        links.link(
            path, "self", GEOJSON, "This page", **kept, limit=query.limit, offset=query.offset
        )
    ]
    if query.offset + len(features) < matched:
        page.append(
            links.link(
                path,
                "next",
                GEOJSON,
                "Next page",
                **kept,
                limit=query.limit,
                offset=query.offset + len(features),
            )
        )
    if query.offset > 0:
        page.append(
            links.link(
                path,
                "prev",
                GEOJSON,
                "Previous page",
                **kept,
                limit=query.limit,
                offset=max(0, query.offset - query.limit),
            )
        )
    page.append(links.link(f"/ogc/collections/{collection_id}", "collection", "application/json"))
    body = {
        "type": "FeatureCollection",
        "features": features,
        "numberMatched": matched,
        "numberReturned": len(features),
        "timeStamp": datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z"),
        "links": page,
    }
    return _json(body, GEOJSON)


@router.get(
    "/collections/{collection_id}/items/{feature_id}",
    summary="One feature (GeoJSON)",
    responses={200: {"content": {GEOJSON: {}}}},
)
def item(
    collection_id: str,
    feature_id: str,
    request: Request,
    session: SessionDep,
    token: SignedIn,
) -> JSONResponse:
    _collection(collection_id)
    feature = (
        get_feature(session, collection_id, row_id, _visible(session, token))
        if (row_id := parse_row_id(feature_id))
        else None
    )
    if feature is None:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND, f"feature {feature_id!r} not found in {collection_id!r}"
        )
    links = Links(request)
    path = f"/ogc/collections/{collection_id}"
    feature["links"] = [
        links.link(f"{path}/items/{feature_id}", "self", GEOJSON),
        links.link(path, "collection", "application/json"),
    ]
    return _json(feature, GEOJSON)
