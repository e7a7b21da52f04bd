"""Measurements on the map: elevation profiles along a line and volumes inside a polygon.

Read-only, so a viewer of the site may make them. The work is the library's
(worker/pipeline/measure.py), bounded to the geometry's window of the rasters.
"""

from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, status
from starlette.concurrency import run_in_threadpool

from backend.api.access import SiteViewer
from backend.api.deps import SessionDep, StorageDep, owned_by_site
from backend.api.routes.comparisons import comparison_of_site
from backend.api.schemas_measure import (
    ProfileOut,
    ProfileRequest,
    VolumeOut,
    VolumeRequest,
    geometry_dict,
)
from backend.db.models import Comparison, Product, Survey
from backend.ids import RowId
from backend.services.comparisons import stage_results
from backend.storage import LocalStorage
from worker.pipeline.errors import InputError
from worker.pipeline.measure import elevation_profile, heights_at, polygon_volume

router = APIRouter(prefix="/sites/{site_id}", tags=["measurements"])


def _product_path(storage: LocalStorage, products: list[Product], kind: str) -> Path | None:
    product = next((p for p in products if p.kind == kind), None)
    if product is None:
        return None
    path = storage.absolute(product.file.path)
    return path if path.is_file() else None


def _comparison_rasters(storage: LocalStorage, comparison: Comparison) -> dict[str, Path | None]:
    """The rasters a comparison is measured on: the pre DSM, the co-registered post DSM
    (on the pre's grid) and Δh; None where one is not made (yet)."""
    return {
        "pre": _product_path(storage, comparison.pre_survey.products, "dsm"),
        "post": _product_path(storage, comparison.products, "post_coregistered"),
        "dh": _product_path(storage, comparison.products, "dh"),
    }


def _need(path: Path | None, what: str) -> Path:
    if path is None:
        raise HTTPException(status.HTTP_409_CONFLICT, f"{what} does not exist yet")
    return path


@router.post(
    "/comparisons/{comparison_id}/profile",
    response_model=ProfileOut,
    summary="Elevation profile of the pre and the co-registered post DSM along a line",
)
async def comparison_profile(
    comparison_id: RowId,
    body: ProfileRequest,
    site: SiteViewer,
    session: SessionDep,
    storage: StorageDep,
) -> ProfileOut:
    rasters = _comparison_rasters(storage, comparison_of_site(session, site, comparison_id))
    pre = _need(rasters["pre"], "the pre survey's DSM")
    post = _need(rasters["post"], "the comparison's co-registered post DSM (it has not run)")
    return await _profile(body, {"pre": pre, "post": post})


@router.post(
    "/surveys/{survey_id}/profile",
    response_model=ProfileOut,
    summary="Elevation profile of a survey's DSM along a line",
)
async def survey_profile(
    survey_id: RowId,
    body: ProfileRequest,
    site: SiteViewer,
    session: SessionDep,
    storage: StorageDep,
) -> ProfileOut:
    survey = owned_by_site(session, Survey, site, survey_id, "survey")
    dsm = _need(_product_path(storage, survey.products, "dsm"), f"survey {survey_id}'s DSM")
    return await _profile(body, {"dsm": dsm})


async def _profile(body: ProfileRequest, rasters: dict[str, Path]) -> ProfileOut:
    try:
        profile = await run_in_threadpool(
            elevation_profile, geometry_dict(body.line), rasters, body.samples
        )
    except InputError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    return ProfileOut(**profile.to_dict())


@router.post(
    "/comparisons/{comparison_id}/volume",
    response_model=VolumeOut,
    summary="Cut, fill and net volume between pre and post inside a polygon, with the LoD",
)
async def comparison_volume(
    comparison_id: RowId,
    body: VolumeRequest,
    site: SiteViewer,
    session: SessionDep,
    storage: StorageDep,
) -> VolumeOut:
    comparison = comparison_of_site(session, site, comparison_id)
    dh = _need(
        _product_path(storage, comparison.products, "dh"), "the comparison's Δh (it has not run)"
    )
    # The per-cell LoD where the method made one; else the comparison's one LoD, if any.
    lod: Path | float | None = _product_path(storage, comparison.products, "lod")
    if lod is None:
        lod = (stage_results(comparison, None).get("difference") or {}).get("lod_m")
    try:
        volume = await run_in_threadpool(polygon_volume, geometry_dict(body.polygon), dh, lod)
    except InputError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    return VolumeOut(**volume.to_dict())


Longitude = Annotated[float, Query(ge=-180, le=180, description="WGS84 longitude")]
Latitude = Annotated[float, Query(ge=-90, le=90, description="WGS84 latitude")]


@router.get(
    "/comparisons/{comparison_id}/heights",
    summary="Pre, co-registered post and Δh at one point (null where a raster has none)",
)
async def comparison_heights(
    comparison_id: RowId,
    lon: Longitude,
    lat: Latitude,
    site: SiteViewer,
    session: SessionDep,
    storage: StorageDep,
) -> dict[str, float | None]:
    rasters = _comparison_rasters(storage, comparison_of_site(session, site, comparison_id))
    found = {name: path for name, path in rasters.items() if path is not None}
    values = await run_in_threadpool(heights_at, lon, lat, found)
    return {name: values.get(name) for name in rasters}


@router.get(
    "/surveys/{survey_id}/heights",
    summary="A survey's DSM height at one point (null outside it)",
)
async def survey_heights(
    survey_id: RowId,
    lon: Longitude,
    lat: Latitude,
    site: SiteViewer,
    session: SessionDep,
    storage: StorageDep,
) -> dict[str, float | None]:
    survey = owned_by_site(session, Survey, site, survey_id, "survey")
    dsm = _need(_product_path(storage, survey.products, "dsm"), f"survey {survey_id}'s DSM")
    return await run_in_threadpool(heights_at, lon, lat, {"dsm": dsm})
