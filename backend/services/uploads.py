"""Resumable uploads (the tus protocol, 1.0.0): bytes accumulate in storage until complete.

An upload is created with its length and metadata (which site, what it is), checked in plain
words before any byte is sent; each PATCH appends at the offset the server reports, so a
dropped connection or a reloaded page goes on where it stopped. When the last byte arrives
the whole file's SHA-256 is checked against the one the client announced, and the file is
handed over, at once and whole, to the service that makes it a survey (a DSM) or a
survey's input (video, flight log, photo). Until then it lives as
`uploads/{site_id}/{upload_id}.part` under storage and nowhere else; a video survey may
be processed from that file while it grows (survey_sources.submit_reconstruction).

Extensions: creation, termination, checksum (sha256, per request) and expiration.
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import fcntl
import hashlib
import logging
import os
import re
import uuid
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from backend.config import Settings
from backend.db.arriving_uploads import part_path, part_relative_path
from backend.db.models import Site, Survey, Upload, UploadState
from backend.db.tokens import as_utc
from backend.ids import parse_row_id
from backend.raster_limits import RasterLimits
from backend.services.survey_sources import (
    SourceRejected,
    add_survey_file,
    check_file_name,
    file_refusal,
)
from backend.services.surveys import create_dsm_survey_from_file
from backend.storage import LocalStorage, file_digest
from worker.pipeline.errors import InputError

TUS_VERSION = "1.0.0"
TUS_EXTENSIONS = ("creation", "termination", "checksum", "expiration")
CHECKSUM_ALGORITHMS = ("sha256",)
PURPOSES = ("dsm", "survey_file")
DSM_SUFFIXES = (".tif", ".tiff")
logger = logging.getLogger(__name__)


class UploadError(Exception):
    """A request the upload cannot take; `status` is the HTTP answer, the message says why."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class Checksum:
    algorithm: str
    digest: bytes


def parse_metadata(header: str | None) -> dict[str, str]:
    """`Upload-Metadata`: comma-separated `key base64value` pairs (the value may be absent)."""
    metadata: dict[str, str] = {}
    if not header:
        return metadata
    for pair in header.split(","):
        parts = pair.strip().split(" ")
        if not parts[0] or len(parts) > 2:
            raise UploadError(400, f"Upload-Metadata pair {pair.strip()!r} is not 'key base64'")
        try:
            value = base64.b64decode(parts[1], validate=True).decode() if len(parts) == 2 else ""
        except (binascii.Error, UnicodeDecodeError):
            raise UploadError(400, f"Upload-Metadata {parts[0]!r} is not base64 text") from None
        metadata[parts[0]] = value
    return metadata


def parse_checksum(header: str | None) -> Checksum | None:
    """`Upload-Checksum: sha256 <base64 digest>` of one PATCH body."""
    if not header:
        return None
    algorithm, _, encoded = header.strip().partition(" ")
    if algorithm not in CHECKSUM_ALGORITHMS:
        raise UploadError(400, f"checksum algorithm {algorithm!r} is not supported; use sha256")
    try:
        digest = base64.b64decode(encoded, validate=True)
    except binascii.Error:
        raise UploadError(400, "Upload-Checksum must be 'sha256 <base64 digest>'") from None
    return Checksum(algorithm, digest)


def _required(metadata: dict[str, str], key: str, what: str) -> str:
    value = metadata.get(key, "").strip()
    if not value:
        raise UploadError(400, f"the upload's metadata lacks {key!r} ({what})")
    return value


def _captured_at(value: str) -> str:
    try:
        moment = datetime.fromisoformat(value.replace("Z", "+00:00"))
    except ValueError:
        raise UploadError(
            400, f"captured_at {value!r} is not a date and time such as 2026-06-01T10:00:00Z"
        ) from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return moment.isoformat()


def check_upload_request(
    session: Session, settings: Settings, length: int, metadata: dict[str, str]
) -> dict[str, Any]:
    """Everything that can be said about an upload before its bytes come, in plain words.

    Returns the validated details kept with the upload.
    """
    site_text = _required(metadata, "site_id", "the site it belongs to")
    site_id = parse_row_id(site_text)
    if site_id is None or session.get(Site, site_id) is None:
        raise UploadError(404, f"site {site_text} does not exist")
    filename = _required(metadata, "filename", "the file's name")
    if "/" in filename or "\\" in filename or filename in (".", ".."):
        raise UploadError(400, f"file name {filename!r} must not contain a folder")
    if length <= 0:
        raise UploadError(400, f"{filename} is empty")
    if length > settings.max_upload_bytes:
        raise UploadError(
            413,
            f"{filename} has {length} bytes, more than the limit of "
            f"{settings.max_upload_bytes} bytes",
        )
    purpose = metadata.get("purpose", "dsm")
    if purpose not in PURPOSES:
        raise UploadError(400, f"unknown purpose {purpose!r}; purposes: {', '.join(PURPOSES)}")
    sha256 = metadata.get("sha256", "").lower() or None
    if sha256 is not None and not re.fullmatch(r"[0-9a-f]{64}", sha256):
        raise UploadError(400, "sha256 must be the file's SHA-256 as 64 hexadecimal digits")
    details: dict[str, Any] = {"site_id": site_id, "filename": filename, "sha256": sha256}
    if purpose == "dsm":
        if not filename.lower().endswith(DSM_SUFFIXES):
            raise UploadError(
                415, f"{filename} is not a GeoTIFF: a DSM must be a .tif or .tiff file"
            )
        details["captured_at"] = _captured_at(
            _required(metadata, "captured_at", "when the survey was flown")
        )
        details["name"] = metadata.get("name", "").strip()[:200] or filename
    else:
        survey_text = _required(metadata, "survey_id", "the survey it belongs to")
        role = _required(metadata, "role", "video, log or image")
        survey_id = parse_row_id(survey_text)
        survey = session.get(Survey, survey_id) if survey_id is not None else None
        if survey is None or survey.site_id != details["site_id"]:
            raise UploadError(404, f"survey {survey_text} not found in site {site_text}")
        try:
            check_file_name(filename, role)
        except InputError as exc:
            raise UploadError(415, str(exc)) from None
        # The same rule as when the file is handed over (file_refusal): what the survey
        # takes now, whichever of this upload and a request to process comes first.
        refusal = file_refusal(survey, role, filename)
        if refusal is not None:
            raise UploadError(409, refusal)
        details |= {"survey_id": survey.id, "role": role}
    details["purpose"] = purpose
    return details


def current_offset(storage: LocalStorage, upload: Upload) -> int:
    """Bytes received: the part file on disk is the truth (a request may have been cut)."""
    if upload.state != UploadState.receiving:
        return upload.offset
    try:
        return min(part_path(storage, upload).stat().st_size, upload.length)
    except FileNotFoundError:
        return 0


def remove_expired(session: Session, storage: LocalStorage) -> int:
    """Delete unfinished uploads past their expiry, with their bytes."""
    now = datetime.now(UTC)
    expired = [
        u
        for u in session.scalars(select(Upload).where(Upload.state == UploadState.receiving))
        if as_utc(u.expires_at) <= now
    ]
    for upload in expired:
        storage.delete(part_relative_path(upload))
        session.delete(upload)
    session.commit()
    return len(expired)


def create_upload(
    session: Session,
    storage: LocalStorage,
    settings: Settings,
    *,
    length: int,
    metadata: dict[str, str],
    author: str,
) -> Upload:
    remove_expired(session, storage)
    details = check_upload_request(session, settings, length, metadata)
    now = datetime.now(UTC)
    upload = Upload(
        id=uuid.uuid4().hex,
        site_id=details["site_id"],
        purpose=details["purpose"],
        filename=details["filename"],
        length=length,
        offset=0,
        sha256=details["sha256"],
        details=details,
        state=UploadState.receiving,
        created_by=author,
        created_at=now,
        expires_at=now + timedelta(hours=settings.upload_expiry_hours),
    )
    path = part_path(storage, upload)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.touch()
    session.add(upload)
    try:
        session.commit()
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    return upload


@contextlib.contextmanager
def _exclusive(path: Path) -> Iterator[Any]:
    """The part file opened for appending, locked against a second writer (a resumed
    request may arrive while the server still serves the one the client gave up on)."""
    with open(path, "r+b") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UploadError(423, "this upload is receiving another request; try again") from None
        try:
            yield handle
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


async def append(
    session: Session,
    storage: LocalStorage,
    upload: Upload,
    offset: int,
    chunks: AsyncIterator[bytes],
    checksum: Checksum | None,
) -> int:
    """Append a PATCH body at `offset`; return the new offset.

    Without a checksum, the bytes that arrived before a connection broke are kept (the
    client resumes after them); with one, a body that does not match is dropped whole (460).
    """
    if upload.state == UploadState.complete:
        raise UploadError(409, f"upload {upload.id} is complete")
    if upload.state == UploadState.failed:
        raise UploadError(410, f"upload {upload.id} failed: {upload.error}")
    path = part_path(storage, upload)
    if not path.exists():
        raise UploadError(404, f"upload {upload.id} has no data any more; start it again")
    with _exclusive(path) as handle:
        size = os.fstat(handle.fileno()).st_size
        if offset != size:
            raise UploadError(
                409, f"Upload-Offset {offset} does not match the {size} bytes received"
            )
        handle.seek(size)
        digest = hashlib.sha256()
        written = 0
        complete_body = False
        try:
            async for chunk in chunks:
                if size + written + len(chunk) > upload.length:
                    raise UploadError(
                        413, f"more bytes than the {upload.length} announced for {upload.filename}"
                    )
                handle.write(chunk)
                digest.update(chunk)
                written += len(chunk)
            complete_body = True
            if checksum is not None and digest.digest() != checksum.digest:
                raise UploadError(460, "checksum mismatch: the request's data arrived damaged")
        finally:
            handle.flush()
            damaged = checksum is not None and digest.digest() != checksum.digest
            # A cut connection without checksum keeps what arrived: the client resumes after
            # it. With a checksum, only a whole, matching body is kept.
            if damaged or (not complete_body and checksum is not None):
                handle.truncate(size)
            os.fsync(handle.fileno())
            new_offset = os.fstat(handle.fileno()).st_size
            upload.offset = new_offset
            session.commit()
    return new_offset


async def complete(
    session: Session, storage: LocalStorage, upload: Upload, limits: RasterLimits
) -> Upload:
    """Verify the whole file and hand it over; on failure it is removed and the upload
    records why (in plain words) and raises UploadError(422)."""
    path = part_path(storage, upload)
    try:
        size, sha256 = await run_in_threadpool(file_digest, path)
        if size != upload.length:
            raise InputError(f"{upload.filename}: {size} bytes arrived of {upload.length}")
        if upload.sha256 and sha256 != upload.sha256:
            raise InputError(
                f"{upload.filename} arrived damaged: its SHA-256 is {sha256}, the file sent "
                f"had {upload.sha256}; upload it again"
            )
        await _hand_over(session, storage, upload, path, limits)
    except (InputError, SourceRejected) as exc:
        _fail(session, upload, path, str(exc))
        raise UploadError(422, str(exc)) from None
    except Exception as exc:
        # The file may be half-handed over: what is left of it goes, and the upload says
        # so rather than waiting for bytes that cannot complete it any more.
        logger.exception("upload %s could not be handed over", upload.id)
        _fail(session, upload, path, f"the server could not store {upload.filename}: {exc}")
        raise UploadError(
            500, f"the server could not store {upload.filename}; upload it again"
        ) from exc
    return upload


def _fail(session: Session, upload: Upload, path: Path, reason: str) -> None:
    session.rollback()
    path.unlink(missing_ok=True)
    upload.state, upload.error = UploadState.failed, reason
    upload.completed_at = datetime.now(UTC)
    session.commit()


async def _hand_over(
    session: Session, storage: LocalStorage, upload: Upload, path: Path, limits: RasterLimits
) -> None:
    details = upload.details
    if upload.purpose == "dsm":
        site = session.get(Site, upload.site_id)
        survey = await create_dsm_survey_from_file(
            session,
            storage,
            site,  # type: ignore[arg-type]
            path,
            name=details["name"],
            captured_at=datetime.fromisoformat(details["captured_at"]),
            original_name=upload.filename,
            limits=limits,
        )
        survey_id = survey.id
    else:
        # Read afresh: processing may have been asked for since this request began.
        survey = session.get(Survey, details["survey_id"], populate_existing=True)
        if survey is None:
            raise InputError(f"survey {details['survey_id']} was deleted during the upload")
        await run_in_threadpool(
            add_survey_file,
            session,
            storage,
            survey,
            role=details["role"],
            filename=upload.filename,
            source=path,
        )
        survey_id = survey.id
    upload.state = UploadState.complete
    upload.survey_id = survey_id
    upload.offset = upload.length
    upload.completed_at = datetime.now(UTC)
    session.commit()


def terminate(session: Session, storage: LocalStorage, upload: Upload) -> None:
    """Forget the upload and its bytes (a survey already made from it stays)."""
    storage.delete(part_relative_path(upload))
    session.delete(upload)
    session.commit()
