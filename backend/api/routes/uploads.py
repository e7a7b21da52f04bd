"""Resumable uploads: a tus 1.0.0 server (creation, termination, checksum, expiration).

    OPTIONS /uploads                what this server supports (no token needed)
    POST    /uploads                create: Upload-Length, Upload-Metadata -> 201 Location
    HEAD    /uploads/{upload_id}    Upload-Offset: where to resume
    PATCH   /uploads/{upload_id}    append at Upload-Offset (application/offset+octet-stream)
    DELETE  /uploads/{upload_id}    termination
    GET     /uploads/{upload_id}    the upload as JSON: state, error, the survey it made

Metadata (base64 values, as tus-js-client sends them): `site_id`, `filename`, `purpose`
(`dsm` or `survey_file`), `sha256` (the whole file's, checked on completion); for a DSM
`captured_at` and `name`; for a survey's file `survey_id` and `role` (video, log, image).
"""

from email.utils import format_datetime
from typing import Annotated

from fastapi import APIRouter, Header, HTTPException, Request, Response, status
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from backend.api.access import SignedIn, UploadAnalyst
from backend.api.body_limits import streamed_upload
from backend.api.deps import SessionDep, SettingsDep, StorageDep
from backend.api.schemas_map import UploadOut
from backend.db.access import role_on_site
from backend.db.models import ApiToken, Role, Site, Upload, UploadState
from backend.db.tokens import as_utc
from backend.ids import parse_row_id
from backend.raster_limits import RasterLimits
from backend.services.survey_sources import uploaded_file_warnings
from backend.services.tile_prerender_queue import send_prerender_task
from backend.services.uploads import (
    CHECKSUM_ALGORITHMS,
    TUS_EXTENSIONS,
    TUS_VERSION,
    UploadError,
    append,
    complete,
    create_upload,
    current_offset,
    parse_checksum,
    parse_metadata,
    terminate,
)
from backend.services.users import author_of
from backend.storage import LocalStorage

router = APIRouter(prefix="/uploads", tags=["resumable uploads (tus)"])

TUS_HEADERS = {"Tus-Resumable": TUS_VERSION, "Cache-Control": "no-store"}
OFFSET_MEDIA_TYPE = "application/offset+octet-stream"


def _error(exc: UploadError) -> JSONResponse:
    return JSONResponse({"detail": str(exc)}, status_code=exc.status, headers=TUS_HEADERS)


def _check_version(tus_resumable: str | None) -> None:
    if tus_resumable != TUS_VERSION:
        raise HTTPException(
            status.HTTP_412_PRECONDITION_FAILED,
            f"send 'Tus-Resumable: {TUS_VERSION}' (this server speaks tus {TUS_VERSION})",
            headers={"Tus-Version": TUS_VERSION},
        )


def _expires(upload: Upload) -> dict[str, str]:
    if upload.state != UploadState.receiving:
        return {}
    return {"Upload-Expires": format_datetime(as_utc(upload.expires_at), usegmt=True)}


@router.options("", status_code=status.HTTP_204_NO_CONTENT, summary="tus: what is supported")
def tus_options(settings: SettingsDep) -> Response:
    return Response(
        status_code=status.HTTP_204_NO_CONTENT,
        headers={
            **TUS_HEADERS,
            "Tus-Version": TUS_VERSION,
            "Tus-Extension": ",".join(TUS_EXTENSIONS),
            "Tus-Max-Size": str(settings.max_upload_bytes),
            "Tus-Checksum-Algorithm": ",".join(CHECKSUM_ALGORITHMS),
        },
    )


def _may_upload_to(session: SessionDep, token: ApiToken, site_text: str) -> None:
    """An upload goes to a site the token is an analyst on; one it cannot see does not
    exist for it (the service says which site is missing, whatever the reason)."""
    site_id = parse_row_id(site_text.strip())
    site = session.get(Site, site_id) if site_id is not None else None
    role = role_on_site(session, token, site) if site is not None else None
    if site is not None and role is None:
        raise UploadError(404, f"site {site_text.strip()} does not exist")
    if role is not None and role.rank < Role.analyst.rank:
        raise UploadError(403, f"uploading needs the role analyst on site {site_id}")


@router.post("", status_code=status.HTTP_201_CREATED, summary="tus: create an upload")
def create(
    request: Request,
    token: SignedIn,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    upload_length: Annotated[int | None, Header()] = None,
    upload_metadata: Annotated[str | None, Header()] = None,
    tus_resumable: Annotated[str | None, Header()] = None,
) -> Response:
    _check_version(tus_resumable)
    if upload_length is None:
        return _error(UploadError(400, "Upload-Length is missing: say how many bytes will come"))
    try:
        metadata = parse_metadata(upload_metadata)
        _may_upload_to(session, token, metadata.get("site_id", ""))
        upload = create_upload(
            session,
            storage,
            settings,
            length=upload_length,
            metadata=metadata,
            author=author_of(token),
        )
    except UploadError as exc:
        return _error(exc)
    location = str(request.url_for("upload_status", upload_id=upload.id).path)
    return Response(
        status_code=status.HTTP_201_CREATED,
        headers={**TUS_HEADERS, "Location": location, **_expires(upload)},
    )


@router.head("/{upload_id}", summary="tus: the offset to resume at")
def offset(
    upload: UploadAnalyst,
    storage: StorageDep,
    tus_resumable: Annotated[str | None, Header()] = None,
) -> Response:
    _check_version(tus_resumable)
    if upload.state == UploadState.failed:
        return Response(status_code=status.HTTP_410_GONE, headers=TUS_HEADERS)
    return Response(
        status_code=status.HTTP_200_OK,
        headers={
            **TUS_HEADERS,
            "Upload-Offset": str(current_offset(storage, upload)),
            "Upload-Length": str(upload.length),
            **_expires(upload),
        },
    )


@router.patch(
    "/{upload_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="tus: append bytes at Upload-Offset; the last ones complete the upload",
    description="When the last byte arrives the file is checked (SHA-256 given at creation, "
    "then as a DSM or a survey's file): 422 with the reason if it cannot be used.",
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {OFFSET_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
        }
    },
)
@streamed_upload
async def patch(
    upload: UploadAnalyst,
    request: Request,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    upload_offset: Annotated[int | None, Header()] = None,
    upload_checksum: Annotated[str | None, Header()] = None,
    tus_resumable: Annotated[str | None, Header()] = None,
) -> Response:
    _check_version(tus_resumable)
    if request.headers.get("content-type") != OFFSET_MEDIA_TYPE:
        return _error(UploadError(415, f"a PATCH must be sent as {OFFSET_MEDIA_TYPE}"))
    if upload_offset is None:
        return _error(UploadError(400, "Upload-Offset is missing"))
    try:
        checksum = parse_checksum(upload_checksum)
        new_offset = await append(
            session, storage, upload, upload_offset, request.stream(), checksum
        )
        if new_offset == upload.length:
            await complete(session, storage, upload, RasterLimits.from_settings(settings))
            if upload.purpose == "dsm" and upload.survey_id is not None:
                await run_in_threadpool(send_prerender_task, settings, "surveys", upload.survey_id)
    except UploadError as exc:
        return _error(exc)
    except ClientDisconnect:
        # The bytes that arrived are kept; the client asks HEAD where to go on.
        return Response(status_code=status.HTTP_400_BAD_REQUEST, headers=TUS_HEADERS)
    return Response(
        status_code=status.HTTP_204_NO_CONTENT,
        headers={**TUS_HEADERS, "Upload-Offset": str(new_offset), **_expires(upload)},
    )


@router.delete(
    "/{upload_id}", status_code=status.HTTP_204_NO_CONTENT, summary="tus: cancel an upload"
)
def delete(
    upload: UploadAnalyst,
    session: SessionDep,
    storage: StorageDep,
    tus_resumable: Annotated[str | None, Header()] = None,
) -> Response:
    _check_version(tus_resumable)
    terminate(session, storage, upload)
    return Response(status_code=status.HTTP_204_NO_CONTENT, headers=TUS_HEADERS)


def upload_out(session: Session, storage: LocalStorage, upload: Upload) -> UploadOut:
    out = UploadOut.model_validate(upload)
    out.offset = current_offset(storage, upload)
    out.warnings = uploaded_file_warnings(session, upload)
    details = upload.details or {}
    if upload.purpose == "survey_file":
        out.survey_id = out.survey_id or details.get("survey_id")
        out.role = details.get("role")
    return out


@router.get("/{upload_id}", response_model=UploadOut, summary="The upload's state as JSON")
def upload_status(upload: UploadAnalyst, session: SessionDep, storage: StorageDep) -> UploadOut:
    return upload_out(session, storage, upload)
