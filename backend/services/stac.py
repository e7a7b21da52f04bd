"""A STAC catalog of sites, surveys and comparisons, built with pystac.

    catalog.json                          the root: one child Collection per site
    sites/{id}/collection.json            a site: its surveys' extent; one Item per survey
                                          and per finished comparison
    sites/{id}/surveys/{id}/item.json     a survey: footprint, capture time, COG DSM asset
    sites/{id}/comparisons/{id}/item.json a comparison: Δh, significance, co-registered DSM
                                          (COGs) and detections (GeoJSON)

Hrefs are absolute URLs of this API (`href(path)` makes them), so the JSON can be served
as is. Items carry the projection extension with `proj:code` (e.g. "EPSG:32633").
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import pystac
from pystac.extensions.projection import ProjectionExtension
from shapely.geometry import shape
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import Comparison, JobState, Product, Site, Survey
from backend.geotiff import open_geotiff
from backend.storage import LocalStorage
from backend.urls import api_url
from worker.pipeline.geo import geojson_rfc7946

Href = Callable[[str], str]
COG = pystac.MediaType.COG

ASSET_ROLES = {
    "dsm": (["data"], "DSM (Cloud-Optimized GeoTIFF, metres)"),
    # STAC's role for a true-colour image a person looks at.
    "orthophoto": (["visual"], "True orthophoto on the DSM (RGBA Cloud-Optimized GeoTIFF)"),
    "points": (["data"], "Point cloud the DSM is made of (PLY, UTM)"),
    "trajectory": (["metadata"], "Flight path (GeoJSON, WGS84)"),
    "report": (["metadata"], "Reconstruction report: figures, timings, warnings (JSON)"),
    "post_coregistered": (["data"], "Post DSM co-registered onto the pre DSM (COG, metres)"),
    "dh": (["data"], "Δh = post − pre (COG, metres)"),
    "significance": (["data"], "Significant change: 1 loss, 2 gain (COG)"),
    "lod": (["data"], "Per-pixel level of detection, LoD95 (COG, metres)"),
    "detections": (["data"], "Detected landslides (GeoJSON, WGS84)"),
}


def _aware(moment: datetime) -> datetime:
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def _link(rel: str, href: str, media_type: str, title: str | None = None) -> pystac.Link:
    return pystac.Link(rel, href, media_type=media_type, title=title)


def _plain(obj: pystac.STACObject, root_href: str) -> dict[str, Any]:
    obj.remove_links("root")  # pystac makes a lone catalog its own root
    obj.add_link(_link("root", root_href, pystac.MediaType.JSON, "slidewatch"))
    return obj.to_dict(include_self_link=True, transform_hrefs=False)


def _ready_comparisons(session: Session, site_id: int) -> list[Comparison]:
    return list(
        session.scalars(
            select(Comparison)
            .where(Comparison.site_id == site_id, Comparison.status == JobState.succeeded)
            .order_by(Comparison.id)
        )
    )


def _surveys(session: Session, site_id: int) -> list[Survey]:
    return list(
        session.scalars(select(Survey).where(Survey.site_id == site_id).order_by(Survey.id))
    )


def root_catalog(session: Session, href: Href, visible: set[int] | None = None) -> dict[str, Any]:
    """The catalog of the sites in `visible` (None: every site)."""
    catalog = pystac.Catalog(
        id="slidewatch",
        title="slidewatch",
        description="Drone surveys of monitored slopes and the landslides found between them.",
    )
    catalog.set_self_href(href("/stac/catalog.json"))
    query = select(Site).order_by(Site.id)
    if visible is not None:
        query = query.where(Site.id.in_(visible))
    for site in session.scalars(query):
        catalog.add_link(
            _link(
                "child",
                href(f"/stac/sites/{site.id}/collection.json"),
                "application/json",
                site.name,
            )
        )
    return _plain(catalog, href("/stac/catalog.json"))


def site_collection(session: Session, site: Site, href: Href) -> dict[str, Any]:
    surveys = _surveys(session, site.id)
    footprints = [shape(s.footprint) for s in surveys if s.footprint]
    if footprints:
        west = min(f.bounds[0] for f in footprints)
        south = min(f.bounds[1] for f in footprints)
        east = max(f.bounds[2] for f in footprints)
        north = max(f.bounds[3] for f in footprints)
        bbox = [west, south, east, north]
    else:
        bbox = [-180.0, -90.0, 180.0, 90.0]
    times = [_aware(s.captured_at) for s in surveys]
    interval = [min(times), max(times)] if times else [None, None]
    collection = pystac.Collection(
        id=f"site-{site.id}",
        title=site.name,
        description=site.description or f"Surveys and comparisons of site {site.name}",
        extent=pystac.Extent(
            pystac.SpatialExtent([bbox]),
            pystac.TemporalExtent([interval]),  # type: ignore[list-item]
        ),
        license="other",
    )
    collection.set_self_href(href(f"/stac/sites/{site.id}/collection.json"))
    collection.add_link(_link("parent", href("/stac/catalog.json"), pystac.MediaType.JSON))
    for survey in surveys:
        collection.add_link(
            _link(
                "item",
                href(f"/stac/sites/{site.id}/surveys/{survey.id}/item.json"),
                pystac.MediaType.GEOJSON,
                survey.name,
            )
        )
    for comparison in _ready_comparisons(session, site.id):
        collection.add_link(
            _link(
                "item",
                href(f"/stac/sites/{site.id}/comparisons/{comparison.id}/item.json"),
                pystac.MediaType.GEOJSON,
                f"comparison {comparison.id}",
            )
        )
    return _plain(collection, href("/stac/catalog.json"))


def _projection(item: pystac.Item, crs: str | None, raster_path: Any | None) -> None:
    projection = ProjectionExtension.ext(item, add_if_missing=True)
    if crs and crs.upper().startswith("EPSG:"):
        projection.code = crs.upper()
    elif crs:
        projection.wkt2 = crs
    if raster_path is not None:
        with open_geotiff(raster_path) as src:
            projection.shape = [src.height, src.width]
            projection.transform = list(src.transform)[:6]
            projection.bbox = list(src.bounds)


def _add_assets(
    item: pystac.Item, products: list[Product], storage: LocalStorage, href: Href
) -> Any | None:
    """Add one asset per product; return the path of the DSM or Δh (for proj:shape)."""
    main = None
    for product in sorted(products, key=lambda p: p.kind):
        roles, title = ASSET_ROLES.get(product.kind, (["data"], product.kind))
        is_raster = product.file.media_type.startswith("image/tiff")
        asset = pystac.Asset(
            href=href(api_url("sites", product.site_id, "products", product.id, "file")),
            title=title,
            media_type=COG if is_raster else product.file.media_type,
            roles=roles,
            extra_fields={"file:size": product.file.size_bytes},
        )
        item.add_asset(product.kind, asset)
        if product.kind in ("dsm", "dh"):
            path = storage.absolute(product.file.path)
            main = path if path.is_file() else main
    return main


def survey_item(
    session: Session, storage: LocalStorage, survey: Survey, href: Href
) -> dict[str, Any]:
    geometry = survey.footprint
    bbox = list(shape(geometry).bounds) if geometry else None
    item = pystac.Item(
        id=f"survey-{survey.id}",
        geometry=geometry,
        bbox=bbox,
        datetime=_aware(survey.captured_at),
        properties={"title": survey.name, "gsd": survey.resolution_m},
        collection=f"site-{survey.site_id}",
    )
    main = _add_assets(item, list(survey.products), storage, href)
    _projection(item, survey.crs, main)
    _item_links(item, survey.site_id, f"surveys/{survey.id}", href)
    return _plain(item, href("/stac/catalog.json"))


def comparison_item(
    session: Session, storage: LocalStorage, comparison: Comparison, href: Href
) -> dict[str, Any]:
    pre, post = comparison.pre_survey, comparison.post_survey
    geometry = None
    if pre.footprint and post.footprint:
        geometry = geojson_rfc7946(shape(pre.footprint).intersection(shape(post.footprint)))
    summary = comparison.summary or {}
    item = pystac.Item(
        id=f"comparison-{comparison.id}",
        geometry=geometry,
        bbox=list(shape(geometry).bounds) if geometry else None,
        datetime=_aware(post.captured_at),
        properties={
            "title": f"comparison {comparison.id}: surveys {pre.id} → {post.id}",
            "start_datetime": pystac.utils.datetime_to_str(_aware(pre.captured_at)),
            "end_datetime": pystac.utils.datetime_to_str(_aware(post.captured_at)),
            "slidewatch:method": comparison.method,
            "slidewatch:detections": summary.get("detections"),
            "slidewatch:total_area_m2": summary.get("total_area_m2"),
        },
        collection=f"site-{comparison.site_id}",
    )
    main = _add_assets(item, list(comparison.products), storage, href)
    crs = next((p.crs for p in comparison.products if p.kind == "dh"), None)
    _projection(item, crs, main)
    _item_links(item, comparison.site_id, f"comparisons/{comparison.id}", href)
    item.add_link(
        _link(
            "derived_from",
            href(f"/stac/sites/{comparison.site_id}/surveys/{pre.id}/item.json"),
            pystac.MediaType.GEOJSON,
        )
    )
    item.add_link(
        _link(
            "derived_from",
            href(f"/stac/sites/{comparison.site_id}/surveys/{post.id}/item.json"),
            pystac.MediaType.GEOJSON,
        )
    )
    return _plain(item, href("/stac/catalog.json"))


def _item_links(item: pystac.Item, site_id: int, owner_path: str, href: Href) -> None:
    item.set_self_href(href(f"/stac/sites/{site_id}/{owner_path}/item.json"))
    item.add_link(
        _link("parent", href(f"/stac/sites/{site_id}/collection.json"), pystac.MediaType.JSON)
    )
    item.add_link(
        _link("collection", href(f"/stac/sites/{site_id}/collection.json"), pystac.MediaType.JSON)
    )
    item.add_link(
        _link(
            "wmts",
            href(api_url("sites", site_id, owner_path, "wmts", "WMTSCapabilities.xml")),
            "application/xml",
            "Map layers (WMTS)",
        )
    )
