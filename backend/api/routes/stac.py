"""STAC: a static-style catalog of sites, surveys and comparisons (see services/stac.py)."""

from collections.abc import Callable

from fastapi import APIRouter, HTTPException, Request, status
from fastapi.responses import JSONResponse

from backend.api.access import SignedIn, SiteViewer
from backend.api.deps import SessionDep, StorageDep, owned_by_site, public_base
from backend.db.access import visible_site_ids
from backend.db.models import Comparison, JobState, Survey
from backend.ids import RowId
from backend.services import stac

router = APIRouter(prefix="/stac", tags=["STAC"])


def _href(request: Request) -> Callable[[str], str]:
    """Absolute URLs of this API at its public URL, with no token in them."""
    base = public_base(request)
    return lambda path: f"{base}{path}"


@router.get("/catalog.json", summary="The root STAC catalog: one collection per site")
def catalog(request: Request, session: SessionDep, token: SignedIn) -> JSONResponse:
    """Only the sites this token may see."""
    return JSONResponse(
        stac.root_catalog(session, _href(request), visible_site_ids(session, token))
    )


@router.get("/sites/{site_id}/collection.json", summary="The STAC collection of a site")
def site_collection(request: Request, site: SiteViewer, session: SessionDep) -> JSONResponse:
    return JSONResponse(stac.site_collection(session, site, _href(request)))


@router.get(
    "/sites/{site_id}/surveys/{survey_id}/item.json",
    summary="The STAC item of a survey, with its COG DSM",
    responses={200: {"content": {"application/geo+json": {}}}},
)
def survey_item(
    survey_id: RowId, request: Request, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> JSONResponse:
    survey = owned_by_site(session, Survey, site, survey_id, "survey")
    body = stac.survey_item(session, storage, survey, _href(request))
    return JSONResponse(body, media_type="application/geo+json")


@router.get(
    "/sites/{site_id}/comparisons/{comparison_id}/item.json",
    summary="The STAC item of a finished comparison, with its Δh and detections",
    responses={200: {"content": {"application/geo+json": {}}}},
)
def comparison_item(
    comparison_id: RowId,
    request: Request,
    site: SiteViewer,
    session: SessionDep,
    storage: StorageDep,
) -> JSONResponse:
    comparison = owned_by_site(session, Comparison, site, comparison_id, "comparison")
    if comparison.status != JobState.succeeded:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            f"comparison {comparison_id} is {comparison.status}: its items exist once it succeeds",
        )
    body = stac.comparison_item(session, storage, comparison, _href(request))
    return JSONResponse(body, media_type="application/geo+json")
