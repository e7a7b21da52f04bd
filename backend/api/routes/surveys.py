from datetime import UTC, datetime
from typing import Annotated

from fastapi import APIRouter, Header, HTTPException, Query, Request, Response, status
from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from backend.api.access import SignedIn, SiteAnalyst, SiteManager, SiteViewer
from backend.api.body_limits import streamed_upload
from backend.api.deps import SessionDep, SettingsDep, StorageDep, owned_by_site
from backend.api.schemas import ProductOut, SurveyOut, SurveyUpdate
from backend.api.serializers import product_out, survey_out
from backend.db.models import Site, Survey
from backend.ids import RowId
from backend.raster_limits import RasterLimits
from backend.services.audit import record
from backend.services.deletion import StillInUse, delete_survey
from backend.services.surveys import create_dsm_survey
from backend.services.tile_prerender_queue import send_prerender_task
from backend.storage import UploadTooLarge
from worker.pipeline.errors import InputError

router = APIRouter(prefix="/sites/{site_id}/surveys", tags=["surveys"])


def survey_of_site(session: SessionDep, site: Site, survey_id: RowId) -> Survey:
    return owned_by_site(session, Survey, site, survey_id, "survey")


@router.get("", response_model=list[SurveyOut])
def list_surveys(site: SiteViewer, session: SessionDep, storage: StorageDep) -> list[SurveyOut]:
    query = select(Survey).where(Survey.site_id == site.id).order_by(Survey.captured_at, Survey.id)
    return [survey_out(s, storage) for s in session.scalars(query)]


@router.post(
    "",
    response_model=SurveyOut,
    status_code=status.HTTP_201_CREATED,
    summary="Upload a DSM GeoTIFF as a new survey",
    description="Send the GeoTIFF as the raw request body, e.g. "
    "`curl -H 'Authorization: Bearer TOKEN' -H 'Content-Type: image/tiff' "
    "--data-binary @dsm.tif 'URL?name=June&captured_at=2026-06-01T10:00:00Z'`. "
    "The body is streamed to disk; uploads above the configured limit are refused with 413.",
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {"image/tiff": {"schema": {"type": "string", "format": "binary"}}},
        }
    },
)
@streamed_upload
async def upload_dsm_survey(
    request: Request,
    site: SiteAnalyst,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    captured_at: Annotated[datetime, Query(description="When the survey was flown (ISO 8601).")],
    name: Annotated[str | None, Query(max_length=200)] = None,
    filename: Annotated[
        str | None, Query(max_length=512, description="Original file name.")
    ] = None,
    content_length: Annotated[int | None, Header()] = None,
) -> Survey:
    content_type = request.headers.get("content-type", "")
    if content_type.startswith("multipart/"):
        raise HTTPException(
            status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
            "send the GeoTIFF as the raw request body (Content-Type: image/tiff), not as a form",
        )
    if content_length is not None and content_length > settings.max_upload_bytes:
        raise HTTPException(
            status.HTTP_413_CONTENT_TOO_LARGE,
            f"upload of {content_length} bytes is larger than the limit of "
            f"{settings.max_upload_bytes} bytes",
        )
    if captured_at.tzinfo is None:
        captured_at = captured_at.replace(tzinfo=UTC)
    try:
        survey = await create_dsm_survey(
            session,
            storage,
            site,
            request.stream(),
            name=name or filename or f"survey {captured_at:%Y-%m-%d %H:%M}",
            captured_at=captured_at,
            original_name=filename,
            max_bytes=settings.max_upload_bytes,
            limits=RasterLimits.from_settings(settings),
        )
    except UploadTooLarge as exc:
        raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, str(exc)) from None
    except InputError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    await run_in_threadpool(send_prerender_task, settings, "surveys", survey.id)
    return survey


@router.get("/{survey_id}", response_model=SurveyOut)
def get_survey(
    survey_id: RowId, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> SurveyOut:
    return survey_out(survey_of_site(session, site, survey_id), storage)


@router.get("/{survey_id}/products", response_model=list[ProductOut])
def list_survey_products(
    survey_id: RowId, site: SiteViewer, session: SessionDep
) -> list[ProductOut]:
    survey = survey_of_site(session, site, survey_id)
    return [product_out(p) for p in survey.products]


@router.patch("/{survey_id}", response_model=SurveyOut, summary="Rename a survey")
def update_survey(
    survey_id: RowId,
    body: SurveyUpdate,
    site: SiteAnalyst,
    session: SessionDep,
    storage: StorageDep,
    token: SignedIn,
) -> SurveyOut:
    survey = survey_of_site(session, site, survey_id)
    changes = body.model_dump(exclude_unset=True, exclude_none=True)
    for field, value in changes.items():
        setattr(survey, field, value.strip() if isinstance(value, str) else value)
    record(
        session, token, "survey.update", site=site, target=f"survey {survey.id}",
        details={"fields": sorted(changes)},
    )  # fmt: skip
    session.commit()
    return survey_out(survey, storage)


@router.delete(
    "/{survey_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a survey with its files, products and jobs (409 while a comparison uses it)",
)
def remove_survey(
    survey_id: RowId,
    site: SiteManager,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    token: SignedIn,
) -> Response:
    survey = survey_of_site(session, site, survey_id)
    record(session, token, "survey.delete", site=site, target=f"survey {survey.id} ({survey.name})")
    try:
        delete_survey(session, storage, survey, tile_cache_dir=settings.tile_cache_dir)
    except StillInUse as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    return Response(status_code=status.HTTP_204_NO_CONTENT)
