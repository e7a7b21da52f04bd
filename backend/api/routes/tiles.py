"""Web-map tiles (XYZ), TileJSON and WMTS capabilities of survey and comparison layers.

URL templates (WebMercatorQuad, 256 px PNG):

    /api/v1/sites/{site_id}/surveys/{survey_id}/tiles/{layer}/{z}/{x}/{y}.png
    /api/v1/sites/{site_id}/comparisons/{comparison_id}/tiles/{layer}/{z}/{x}/{y}.png

Layers: surveys `dsm`, `hillshade`; comparisons `dh`, `dsm`, `hillshade` (see
backend/services/tiles.py). `rescale=min,max` and `colormap=name` override the style.
The file read is always resolved from our own ids by `survey_layer` / `comparison_layer`
(the path dependency); no path or URL is taken from the client.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Annotated, Any

import anyio
import anyio.to_thread
from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response, status
from fastapi.security import HTTPAuthorizationCredentials
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from backend.api.access import SiteViewer, declares, site_for
from backend.api.deps import (
    ApiKey,
    BearerCredentials,
    SessionDep,
    StorageDep,
    owned_by_site,
    public_base,
    token_for,
    token_secret,
)
from backend.api.tile_grants import TileGrants, grant_key
from backend.config import Settings
from backend.db.models import Comparison, JobState, Product, Role, Site, Survey
from backend.ids import RowId
from backend.services.post_motion import PostMotion, motion_from_summary
from backend.services.tile_cache import (
    DiskTileCache,
    TileCache,
    TileKey,
    etag_matches,
    file_identity,
    group_name,
)
from backend.services.tiles import (
    LAYERS,
    BadStyle,
    LayerSpec,
    LayerStyle,
    TileOutsideBounds,
    TileTooCostly,
    WmtsLayer,
    check_colormap,
    is_geotiff,
    known_default_rescale,
    layer_info,
    parse_rescale,
    render_tile,
    stored_default_rescale,
    stretched,
    tile_key,
    wmts_capabilities,
)
from backend.storage import LocalStorage
from backend.urls import api_url

router = APIRouter(prefix="/sites/{site_id}", tags=["map tiles"])


@dataclass(frozen=True)
class LayerSource:
    site_id: int
    owner: str
    owner_id: int
    spec: LayerSpec
    path: Path


def _owner_row(session: SessionDep, site: Site, owner: str, owner_id: RowId):
    if owner == "surveys":
        return owned_by_site(session, Survey, site, owner_id, "survey")
    return owned_by_site(session, Comparison, site, owner_id, "comparison")


def _product_path(
    session: SessionDep, storage: StorageDep, owner: str, owner_id: RowId, kind: str
) -> Path | None:
    column = Product.survey_id if owner == "surveys" else Product.comparison_id
    product = session.query(Product).filter(column == owner_id, Product.kind == kind).one_or_none()
    if product is None:
        return None
    path = storage.absolute(product.file.path)
    return path if path.is_file() else None


def _layer_source(
    site: Site, owner: str, owner_id: RowId, layer: str, session: Session, storage: LocalStorage
) -> LayerSource:
    """Our ids (the site's reader checked) to a file we own: no path is taken from a client."""
    layers = LAYERS[owner]
    if layer not in layers:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            f"unknown layer {layer!r} of {owner}; layers: {', '.join(layers)}",
        )
    _owner_row(session, site, owner, owner_id)
    spec = layers[layer]
    path = _product_path(session, storage, owner, owner_id, spec.product_kind)
    if path is None:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            f"{owner[:-1]} {owner_id} has no {spec.product_kind} product yet",
        )
    if not is_geotiff(path):
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            f"the {spec.product_kind} product of {owner[:-1]} {owner_id} is not a GeoTIFF; "
            "only GeoTIFFs are served as tiles",
        )
    return LayerSource(site.id, owner, owner_id, spec, path)


def _tile_grants(request: Request) -> TileGrants[Any]:
    grants = getattr(request.app.state, "tile_grants", None)
    if grants is None:
        settings: Settings = request.app.state.settings
        grants = request.app.state.tile_grants = TileGrants(settings.tile_grant_ttl_s)
    return grants


def _checked_source(
    state: Any, secret: str, site_id: int, owner: str, owner_id: int, layer: str
) -> LayerSource:
    """The full check of a layer's reader, in one session: token, role, product."""
    with state.sessionmaker() as session:
        token = token_for(session, secret)
        site = site_for(session, token, site_id, Role.viewer)
        return _layer_source(site, owner, owner_id, layer, session, state.storage)


async def _granted_source(
    request: Request,
    credentials: HTTPAuthorizationCredentials | None,
    api_key: str | None,
    site_id: int,
    owner: str,
    owner_id: int,
    layer: str,
) -> LayerSource:
    secret = token_secret(credentials, api_key)
    check = partial(_checked_source, request.app.state, secret, site_id, owner, owner_id, layer)
    key = grant_key(secret, site_id, owner, owner_id, layer)
    return await _tile_grants(request).resolve(key, check)


# The path dependencies of tiles and TileJSON: the viewer's check of backend/api/access.py
# and the layer's file, remembered for a few seconds (backend/api/tile_grants.py).
@declares(f"site:{Role.viewer.value}")
async def survey_layer(
    request: Request,
    site_id: RowId,
    survey_id: RowId,
    layer: str,
    credentials: BearerCredentials,
    api_key: ApiKey = None,
) -> LayerSource:
    return await _granted_source(
        request, credentials, api_key, site_id, "surveys", survey_id, layer
    )


@declares(f"site:{Role.viewer.value}")
async def comparison_layer(
    request: Request,
    site_id: RowId,
    comparison_id: RowId,
    layer: str,
    credentials: BearerCredentials,
    api_key: ApiKey = None,
) -> LayerSource:
    return await _granted_source(
        request, credentials, api_key, site_id, "comparisons", comparison_id, layer
    )


def tile_template(base: str, source: LayerSource) -> str:
    """The XYZ template of a layer: at the public URL, with no token in it (a client sends
    its token itself, as a header or its own `api_key`)."""
    layer = api_url(
        "sites", source.site_id, source.owner, source.owner_id, "tiles", source.spec.name
    )
    return f"{base}{layer}/{{z}}/{{x}}/{{y}}.png"


# Browsers keep a tile for a minute without asking, then ask again with its ETag and get
# 304 while the product is unchanged: a product replaced shows within a minute.
TILE_CACHE_CONTROL = "private, max-age=60"
# Renders at once per API process: two overlap one's GIL-free GDAL and zlib work with the
# other's Python; more only queue for the GIL (20 clients asking new tiles got 25 % fewer
# tiles a second with 4 than with 2), and each holds a tile's read in memory.
TILE_RENDERS_AT_ONCE = 2


def _render_limiter(request: Request) -> anyio.CapacityLimiter:
    # Made on first use: a limiter belongs to the event loop of the process that serves.
    limiter = getattr(request.app.state, "tile_render_limiter", None)
    if limiter is None:
        limiter = request.app.state.tile_render_limiter = anyio.CapacityLimiter(
            TILE_RENDERS_AT_ONCE
        )
    return limiter


def _tile_cache(request: Request) -> TileCache:
    cache = getattr(request.app.state, "tile_cache", None)
    if cache is None:
        settings: Settings = request.app.state.settings
        disk = (
            DiskTileCache(settings.tile_cache_dir, settings.tile_disk_cache_bytes)
            if settings.tile_disk_cache_bytes > 0
            else None
        )
        cache = request.app.state.tile_cache = TileCache(settings.tile_cache_bytes, disk)
    return cache


def _render_and_keep(cache: TileCache, key: TileKey, *args: Any, **kwargs: Any) -> bytes:
    png = render_tile(*args, **kwargs)
    cache.put(key, png)  # in the render's thread: the disk write stays off the event loop
    return png


async def _tile(
    request: Request,
    source: LayerSource,
    z: int,
    x: int,
    y: int,
    rescale: str | None,
    colormap: str | None,
    motion: PostMotion | None = None,
    moved_by: str | None = None,
) -> Response:
    """`motion`: the tile drawn moved (an orthophoto onto a comparison's pre survey);
    `moved_by`: the group of the comparison that moves it, whose tiles it then is."""
    if not 0 <= z <= 24 or not (0 <= x < 2**z and 0 <= y < 2**z):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"tile {z}/{x}/{y} does not exist")
    try:
        stretch = parse_rescale(rescale)
        name = check_colormap(colormap)
    except BadStyle as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from None
    spec = source.spec
    settings: Settings = request.app.state.settings
    try:
        identity = file_identity(source.path)
    except FileNotFoundError:
        # Deleted since its reader's grant was checked (backend/api/tile_grants.py).
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            f"{source.owner[:-1]} {source.owner_id} has no {spec.product_kind} product",
        ) from None
    group = group_name(source.owner, source.owner_id) if moved_by is None else moved_by
    cache = _tile_cache(request)
    if stretch is None and stretched(spec):
        # The default stretch is resolved before the key: the page asks for it by its
        # numbers, a GIS by none, and both get the one tile (rendered ahead by a worker).
        stretch = known_default_rescale(
            spec, identity, settings.tile_max_read_pixels
        ) or await run_in_threadpool(
            stored_default_rescale,
            cache.disk,
            group,
            spec,
            source.path,
            settings.tile_max_read_pixels,
        )
    key = tile_key(identity, spec, z, x, y, stretch, name, group, motion)
    headers = {"Cache-Control": TILE_CACHE_CONTROL, "ETag": key.etag}
    if etag_matches(request.headers.get("if-none-match"), key.etag):
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    png = cache.get_memory(key)
    if png is None and cache.disk is not None:
        png = await run_in_threadpool(cache.get_disk, key)
    if png is not None:
        return Response(png, media_type="image/png", headers={**headers, "X-Tile-Cache": "hit"})
    try:
        # Bounded in time as well as in pixels: a render still running when the answer
        # gives up runs on in its thread, but no longer than its bounded read takes.
        with anyio.fail_after(settings.tile_timeout_s):
            png = await anyio.to_thread.run_sync(
                partial(
                    _render_and_keep,
                    cache,
                    key,
                    source.path,
                    spec,
                    z,
                    x,
                    y,
                    stretch,
                    name,
                    max_read_pixels=settings.tile_max_read_pixels,
                    motion=motion,
                ),
                abandon_on_cancel=True,
                limiter=_render_limiter(request),
            )
    except TileOutsideBounds:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND, f"tile {z}/{x}/{y} is outside the layer"
        ) from None
    except TileTooCostly as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    except TimeoutError:
        raise HTTPException(
            status.HTTP_503_SERVICE_UNAVAILABLE,
            f"tile {z}/{x}/{y} was not rendered within {settings.tile_timeout_s:g} s "
            "(SLIDEWATCH_TILE_TIMEOUT_S)",
            headers={"Retry-After": "5"},
        ) from None
    return Response(png, media_type="image/png", headers={**headers, "X-Tile-Cache": "miss"})


async def _tilejson(source: LayerSource, request: Request) -> dict:
    info = await run_in_threadpool(layer_info, source.path)
    base = public_base(request)
    west, south, east, north = info.bounds
    return {
        "tilejson": "3.0.0",
        "name": f"{source.owner[:-1]} {source.owner_id} {source.spec.title}",
        "scheme": "xyz",
        "tiles": [tile_template(base, source)],
        "minzoom": info.minzoom,
        "maxzoom": info.maxzoom,
        "bounds": [west, south, east, north],
        "center": [(west + east) / 2, (south + north) / 2, max(info.minzoom, info.maxzoom - 2)],
        # The default style, for a legend that matches the tiles (hillshade has none).
        "colormap": source.spec.default_colormap,
        "rescale": None
        if source.spec.default_colormap is None
        else list(
            await run_in_threadpool(
                stored_default_rescale,
                _tile_cache(request).disk,
                group_name(source.owner, source.owner_id),
                source.spec,
                source.path,
                request.app.state.settings.tile_max_read_pixels,
            )
        ),
        "unit": "m",
    }


Rescale = Annotated[
    str | None, Query(description="min,max of the colour stretch (default: from the data)")
]
Colormap = Annotated[
    str | None, Query(description="rio-tiler colormap name, e.g. terrain, viridis, rdbu_r")
]
TILE_DOC = {
    "response_class": Response,
    "responses": {200: {"content": {"image/png": {}}}},
}


@router.get(
    "/surveys/{survey_id}/tiles/{layer}/{z}/{x}/{y}.png",
    summary="A map tile (WebMercatorQuad, 256 px PNG) of a survey layer: dsm, hillshade, "
    "orthophoto",
    **TILE_DOC,
)
async def survey_tile(
    request: Request,
    source: Annotated[LayerSource, Depends(survey_layer)],
    z: int,
    x: int,
    y: int,
    rescale: Rescale = None,
    colormap: Colormap = None,
    coregistered_by: Annotated[
        RowId | None,
        Query(
            description="A comparison whose post survey this is: the orthophoto drawn moved by "
            "its co-registration (turned by its rotation about the centre of its grid, then "
            "shifted), onto the pre survey"
        ),
    ] = None,
) -> Response:
    if coregistered_by is None:
        return await _tile(request, source, z, x, y, rescale, colormap)
    if source.spec.style != LayerStyle.image:
        raise HTTPException(
            status.HTTP_422_UNPROCESSABLE_CONTENT,
            "coregistered_by moves orthophoto tiles only; the co-registered post DSM is the "
            "comparison's own dsm and hillshade layers",
        )
    # The reader's grant of the survey's layer is checked above; this is the comparison's
    # motion, kept as long as that grant.
    motion = await _tile_grants(request).resolve(
        ("motion", source.site_id, source.owner_id, coregistered_by),
        partial(_coregistration_motion, request.app.state, source, coregistered_by),
    )
    group = group_name("comparisons", coregistered_by)
    return await _tile(request, source, z, x, y, rescale, colormap, motion, group)


def _coregistration_motion(state: Any, source: LayerSource, comparison_id: int) -> PostMotion:
    """The horizontal correction (rotation and shift) a comparison applied to this survey
    (its post survey)."""
    with state.sessionmaker() as session:
        comparison = session.get(Comparison, comparison_id)
        if comparison is None or comparison.site_id != source.site_id:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"comparison {comparison_id} not found")
        if comparison.post_survey_id != source.owner_id:
            raise HTTPException(
                status.HTTP_422_UNPROCESSABLE_CONTENT,
                f"survey {source.owner_id} is not the post survey of comparison {comparison_id}",
            )
        motion = motion_from_summary(comparison.summary)
    if motion is None:
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"comparison {comparison_id} has no co-registration yet"
        )
    return motion


@router.get(
    "/comparisons/{comparison_id}/tiles/{layer}/{z}/{x}/{y}.png",
    summary="A map tile (WebMercatorQuad, 256 px PNG) of a comparison layer: dh, dsm, hillshade",
    **TILE_DOC,
)
async def comparison_tile(
    request: Request,
    source: Annotated[LayerSource, Depends(comparison_layer)],
    z: int,
    x: int,
    y: int,
    rescale: Rescale = None,
    colormap: Colormap = None,
) -> Response:
    return await _tile(request, source, z, x, y, rescale, colormap)


@router.get(
    "/surveys/{survey_id}/tiles/{layer}/tilejson.json",
    summary="TileJSON 3.0 of a survey layer: XYZ URL template, bounds, zoom levels",
)
async def survey_tilejson(
    source: Annotated[LayerSource, Depends(survey_layer)], request: Request
) -> dict:
    return await _tilejson(source, request)


@router.get(
    "/comparisons/{comparison_id}/tiles/{layer}/tilejson.json",
    summary="TileJSON 3.0 of a comparison layer: XYZ URL template, bounds, zoom levels",
)
async def comparison_tilejson(
    source: Annotated[LayerSource, Depends(comparison_layer)], request: Request
) -> dict:
    return await _tilejson(source, request)


def _layers_of(
    session: SessionDep, storage: StorageDep, site: Site, owners: list[tuple[str, object]]
) -> list[LayerSource]:
    sources = []
    for owner, row in owners:
        for spec in LAYERS[owner].values():
            path = _product_path(session, storage, owner, row.id, spec.product_kind)  # type: ignore[attr-defined]
            if path is not None and is_geotiff(path):
                sources.append(LayerSource(site.id, owner, row.id, spec, path))  # type: ignore[attr-defined]
    return sources


def _wmts_response(
    request: Request, title: str, owners_title: dict, sources: list[LayerSource]
) -> Response:
    base = public_base(request)
    layers = []
    for source in sources:
        template = (
            tile_template(base, source)
            .replace("{z}", "{TileMatrix}")
            .replace("{x}", "{TileCol}")
            .replace("{y}", "{TileRow}")
        )
        owner_title = owners_title[(source.owner, source.owner_id)]
        layers.append(
            WmtsLayer(
                identifier=f"{source.owner[:-1]}-{source.owner_id}-{source.spec.name}",
                title=f"{owner_title}: {source.spec.title}",
                abstract=f"{source.spec.title} of {owner_title}",
                info=layer_info(source.path),
                template=template,
            )
        )
    document = wmts_capabilities(title, f"{base}{request.url.path}", layers)
    return Response(document, media_type="application/xml")


def _survey_title(survey: Survey) -> str:
    return f"survey {survey.id} ({survey.name}, {survey.captured_at:%Y-%m-%d})"


def _comparison_title(comparison: Comparison) -> str:
    return (
        f"comparison {comparison.id} (surveys {comparison.pre_survey_id} → "
        f"{comparison.post_survey_id})"
    )


WMTS_DOC = {
    "summary": "WMTS 1.0.0 capabilities (RESTful): the layers as WebMercatorQuad tiles",
    "response_class": Response,
    "responses": {200: {"content": {"application/xml": {}}}},
}


@router.get("/wmts/WMTSCapabilities.xml", **WMTS_DOC)
def site_wmts(
    request: Request, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> Response:
    """Every layer of every survey and finished comparison of the site."""
    surveys = session.query(Survey).filter(Survey.site_id == site.id).order_by(Survey.id).all()
    comparisons = (
        session.query(Comparison)
        .filter(Comparison.site_id == site.id, Comparison.status == JobState.succeeded)
        .order_by(Comparison.id)
        .all()
    )
    owners = [("surveys", s) for s in surveys] + [("comparisons", c) for c in comparisons]
    titles = {("surveys", s.id): _survey_title(s) for s in surveys}
    titles |= {("comparisons", c.id): _comparison_title(c) for c in comparisons}
    sources = _layers_of(session, storage, site, owners)  # type: ignore[arg-type]
    return _wmts_response(request, f"slidewatch: {site.name}", titles, sources)


def _owner_wmts(
    request: Request,
    site: Site,
    owner: str,
    owner_id: RowId,
    session: SessionDep,
    storage: StorageDep,
) -> Response:
    row = _owner_row(session, site, owner, owner_id)
    title = _survey_title(row) if owner == "surveys" else _comparison_title(row)
    sources = _layers_of(session, storage, site, [(owner, row)])
    return _wmts_response(
        request, f"slidewatch: {site.name}, {title}", {(owner, owner_id): title}, sources
    )


@router.get("/surveys/{survey_id}/wmts/WMTSCapabilities.xml", **WMTS_DOC)
def survey_wmts(
    request: Request, site: SiteViewer, survey_id: RowId, session: SessionDep, storage: StorageDep
) -> Response:
    """The layers of one survey."""
    return _owner_wmts(request, site, "surveys", survey_id, session, storage)


@router.get("/comparisons/{comparison_id}/wmts/WMTSCapabilities.xml", **WMTS_DOC)
def comparison_wmts(
    request: Request,
    site: SiteViewer,
    comparison_id: RowId,
    session: SessionDep,
    storage: StorageDep,
) -> Response:
    """The layers of one comparison."""
    return _owner_wmts(request, site, "comparisons", comparison_id, session, storage)
