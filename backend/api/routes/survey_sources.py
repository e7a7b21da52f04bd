"""Surveys made from drone video + flight log or from geotagged photos: files, then process.

POST   /sites/{site_id}/surveys/sources                 new survey receiving files
PUT    /sites/{site_id}/surveys/{survey_id}/files/{name}?role=video|log|image   raw body
GET    /sites/{site_id}/surveys/{survey_id}/files
DELETE /sites/{site_id}/surveys/{survey_id}/files/{file_id}
POST   /sites/{site_id}/surveys/{survey_id}/process     queue the reconstruction job
       (?recording=N: of a log joined from several recordings, the one to use)
"""

from datetime import UTC
from typing import Annotated

from fastapi import APIRouter, Header, HTTPException, Query, Request, Response, status

from backend.api.access import SiteAnalyst, SiteViewer
from backend.api.body_limits import streamed_upload
from backend.api.deps import CeleryDep, SessionDep, SettingsDep, StorageDep
from backend.api.routes.surveys import survey_of_site
from backend.api.schemas import JobOut, SourceSurveyCreate, SurveyFileOut, SurveyOut
from backend.api.serializers import job_out
from backend.db.models import Survey, SurveyFile
from backend.ids import RowId
from backend.services.survey_sources import (
    ROLES,
    SourceRejected,
    add_survey_file_from_stream,
    choose_recording,
    create_source_survey,
    remove_survey_file,
    submit_reconstruction,
)
from backend.storage import UploadTooLarge
from worker.jobs.control import QueueUnavailable
from worker.pipeline.errors import InputError

router = APIRouter(prefix="/sites/{site_id}/surveys", tags=["surveys from video or photos"])


@router.post("/sources", response_model=SurveyOut, status_code=status.HTTP_201_CREATED)
def create_source(body: SourceSurveyCreate, site: SiteAnalyst, session: SessionDep) -> Survey:
    """A survey to be reconstructed from a video with its flight log, or from photos.

    Add its files with PUT `.../files/{name}`, then POST `.../process`.
    """
    captured_at = body.captured_at
    if captured_at.tzinfo is None:
        captured_at = captured_at.replace(tzinfo=UTC)
    try:
        return create_source_survey(
            session,
            site,
            kind=body.kind,
            name=body.name,
            captured_at=captured_at,
            options=body.options,
        )
    except InputError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None


@router.put(
    "/{survey_id}/files/{filename}",
    response_model=SurveyFileOut,
    status_code=status.HTTP_201_CREATED,
    summary="Add a file (video, flight log or photo) to a survey, as the raw request body",
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}
            },
        }
    },
)
@streamed_upload
async def put_file(
    request: Request,
    survey_id: RowId,
    filename: str,
    site: SiteAnalyst,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    role: Annotated[str, Query(description=f"One of: {', '.join(ROLES)}.")],
    content_length: Annotated[int | None, Header()] = None,
) -> SurveyFile:
    survey = survey_of_site(session, site, survey_id)
    if content_length is not None and content_length > settings.max_upload_bytes:
        raise HTTPException(
            status.HTTP_413_CONTENT_TOO_LARGE,
            f"upload of {content_length} bytes is larger than the limit of "
            f"{settings.max_upload_bytes} bytes",
        )
    try:
        return await add_survey_file_from_stream(
            session,
            storage,
            survey,
            request.stream(),
            role=role,
            filename=filename,
            max_bytes=settings.max_upload_bytes,
        )
    except SourceRejected as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    except UploadTooLarge as exc:
        raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, str(exc)) from None
    except InputError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None


@router.get("/{survey_id}/files", response_model=list[SurveyFileOut])
def list_files(survey_id: RowId, site: SiteViewer, session: SessionDep) -> list[SurveyFile]:
    return list(survey_of_site(session, site, survey_id).files)


@router.delete("/{survey_id}/files/{file_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_file(
    survey_id: RowId, file_id: RowId, site: SiteAnalyst, session: SessionDep, storage: StorageDep
) -> Response:
    survey = survey_of_site(session, site, survey_id)
    try:
        remove_survey_file(session, storage, survey, file_id)
    except LookupError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from None
    except SourceRejected as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post("/{survey_id}/process", response_model=JobOut, status_code=status.HTTP_202_ACCEPTED)
def process(
    survey_id: RowId,
    site: SiteAnalyst,
    session: SessionDep,
    storage: StorageDep,
    celery: CeleryDep,
    recording: Annotated[
        int | None,
        Query(
            description="Of a flight log joined from several recordings, the one to use "
            "(as the log's warning numbers them); by default the one matching the video."
        ),
    ] = None,
) -> JobOut:
    """Queue the reconstruction of the survey's DSM from its files."""
    survey = survey_of_site(session, site, survey_id)
    try:
        if recording is not None:
            choose_recording(session, storage, survey, recording)
        job = submit_reconstruction(celery, session, survey)
    except SourceRejected as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    except InputError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    except QueueUnavailable as exc:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, str(exc)) from None
    return job_out(job)
