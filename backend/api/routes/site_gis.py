"""What a GIS user of a site needs from the page: the site's OGC API, XYZ, WMTS and STAC
addresses, and a comparison's detections as GeoPackage, KML or Shapefile.

The addresses are built here, from SLIDEWATCH_PUBLIC_URL, so that the page shows what the
API serves and never spells a path itself; none holds a token (a GIS client sends its own,
as a header or as `?api_key=`).
"""

from typing import Annotated, Literal

from fastapi import APIRouter, Path, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from backend.api.access import SiteViewer
from backend.api.deps import SessionDep, StorageDep, owned_by_site, public_base
from backend.api.routes.tiles import _layers_of, tile_template
from backend.db.models import Comparison, JobState, Survey
from backend.ids import RowId
from backend.services.detection_export import FORMATS, export_bytes
from backend.urls import api_url

router = APIRouter(prefix="/sites/{site_id}", tags=["gis"])


class XyzLayer(BaseModel):
    title: str
    template: str = Field(description="XYZ URL template ({z}/{x}/{y}), WebMercatorQuad.")


class GisLinks(BaseModel):
    ogc_api: str = Field(description="OGC API – Features landing page.")
    ogc_detections: str = Field(description="The site's detections as OGC API features.")
    wmts: str = Field(description="WMTS capabilities of every layer of the site.")
    stac: str = Field(description="The site's STAC collection.")
    xyz: list[XyzLayer] = Field(description="Each map layer's XYZ template, newest first.")
    authentication: str


@router.get("/gis", response_model=GisLinks, summary="The site's addresses for GIS clients")
def gis_links(
    request: Request, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> GisLinks:
    base = public_base(request)  # SLIDEWATCH_PUBLIC_URL, never the Host header
    surveys = session.query(Survey).filter(Survey.site_id == site.id).order_by(Survey.id).all()
    comparisons = (
        session.query(Comparison)
        .filter(Comparison.site_id == site.id, Comparison.status == JobState.succeeded)
        .order_by(Comparison.id)
        .all()
    )
    names = {("surveys", s.id): f"survey “{s.name}”" for s in surveys}
    names |= {("comparisons", c.id): f"comparison {c.id}" for c in comparisons}
    owners = [("surveys", s) for s in surveys] + [("comparisons", c) for c in comparisons]
    sources = _layers_of(session, storage, site, owners)  # type: ignore[arg-type]
    xyz = [
        XyzLayer(
            title=f"{names[(s.owner, s.owner_id)]}: {s.spec.title}",
            template=tile_template(base, s),
        )
        for s in reversed(sources)
    ]
    return GisLinks(
        ogc_api=f"{base}/ogc",
        ogc_detections=f"{base}/ogc/collections/detections/items?site_id={site.id}",
        wmts=f"{base}{api_url('sites', site.id, 'wmts', 'WMTSCapabilities.xml')}",
        stac=f"{base}/stac/sites/{site.id}/collection.json",
        xyz=xyz,
        authentication="Send your API token as the header 'Authorization: Bearer <token>', "
        "or, where a client cannot send headers, add '?api_key=<token>' to the address. "
        "Make a token on the Account page.",
    )


DetectionFormat = Literal["gpkg", "kml", "shp"]


@router.get(
    "/comparisons/{comparison_id}/detections/{file_format}",
    summary="A comparison's detections as GeoPackage (gpkg), KML (kml) or zipped Shapefile "
    "(shp), with the same labels and fields as the GeoJSON",
    response_class=Response,
    responses={200: {"content": {f.media_type: {} for f in FORMATS.values()}}},
)
async def detections_file(
    comparison_id: RowId,
    file_format: Annotated[DetectionFormat, Path(description="gpkg, kml or shp")],
    site: SiteViewer,
    session: SessionDep,
) -> Response:
    comparison = owned_by_site(session, Comparison, site, comparison_id, "comparison")
    spec = FORMATS[file_format]
    body = await run_in_threadpool(export_bytes, comparison, file_format)
    name = f"comparison-{comparison.id}-detections.{spec.suffix}"
    return Response(
        body,
        media_type=spec.media_type,
        headers={"Content-Disposition": f'attachment; filename="{name}"'},
    )
