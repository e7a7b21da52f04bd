"""Where a resumable upload's bytes are kept until it completes, and which upload brings
a survey's video while the survey is already processing (see survey_sources)."""

from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import Survey, SurveyKind, Upload, UploadState
from backend.storage import LocalStorage
from backend.storage_layout import upload_part_file


def part_relative_path(upload: Upload) -> str:
    return upload_part_file(upload.site_id, upload.id)


def part_path(storage: LocalStorage, upload: Upload) -> Path:
    return storage.absolute(part_relative_path(upload))


def arriving_video(session: Session, survey: Survey) -> Upload | None:
    """The survey's latest resumable upload of its video that has not been handed over
    (still receiving, or failed), if its video file is not there."""
    if survey.kind != SurveyKind.video or any(f.role == "video" for f in survey.files):
        return None
    uploads = session.scalars(
        select(Upload)
        .where(
            Upload.site_id == survey.site_id,
            Upload.purpose == "survey_file",
            Upload.state != UploadState.complete,
        )
        .order_by(Upload.created_at.desc())
    )
    for upload in uploads:
        details = upload.details or {}
        if details.get("survey_id") == survey.id and details.get("role") == "video":
            return upload
    return None
