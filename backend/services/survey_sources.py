"""Surveys made from drone video with its flight log, or from a set of geotagged photos.

A source survey is created first (status `receiving`), its files are added one by one,
each checked as it arrives (the video decodes, the log parses, the photo is geotagged),
and `submit_reconstruction` queues the job that turns them into a DSM (worker/jobs/
reconstruction.py). A file that fails its check is removed with no row left behind.
A file keeps what its check warned about (`SurveyFile.warnings`); a log is read against the
survey's video, and read again when the video arrives or is deleted, so that its warnings
speak of the recording processing will use (a DJI SRT may join several; the user may
choose one, `choose_recording`, or with the survey's option `recording`).

A video survey may be submitted while its video is still arriving through a resumable
upload (the log must be there): the job reads the video as it comes, and the upload,
marked `streamed`, is still handed over to the survey when it completes. Should it fail
its checks then, the job fails with the upload's reason.

Whether a file is taken depends on the survey alone, never on the order of requests
(`file_refusal`): a file is taken while processing has not consumed one of its role, so
an upload that completes just after processing was asked for is never refused. A failed
survey is fixed by replacing a file (its job then runs again from the first stage) and
processed again (`submit_reconstruction` retries its failed job).
"""

import json
import re
import tempfile
from collections.abc import AsyncIterator
from datetime import datetime
from pathlib import Path
from typing import Any

from celery import Celery
from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from backend.db.arriving_uploads import arriving_video
from backend.db.models import (
    Job,
    JobState,
    Site,
    StageState,
    StoredFile,
    Survey,
    SurveyFile,
    SurveyKind,
    SurveyStatus,
    Upload,
    UploadState,
)
from backend.storage import LocalStorage, SavedFile
from backend.storage_layout import survey_files_folder
from worker.jobs.control import JobKindName, QueueUnavailable, new_job, retry_job, start_job
from worker.pipeline.errors import InputError
from worker.pipeline.ingest.images import read_image_metadata
from worker.pipeline.ingest.read_log import read_flight_log
from worker.pipeline.ingest.recordings import VideoClues
from worker.pipeline.ingest.video import probe_video
from worker.pipeline.quality import failed_messages, survey_quality
from worker.pipeline.reconstruction import ReconstructionOptions

ROLES = ("video", "log", "image")
SUFFIXES = {
    "video": (".mp4", ".mov"),
    "log": (".srt", ".csv", ".txt"),
    "image": (".jpg", ".jpeg"),
}
ROLES_OF_KIND = {SurveyKind.video: ("video", "log"), SurveyKind.images: ("image",)}
MIN_IMAGES = 3
MEDIA_TYPES = {"video": "video/mp4", "log": "text/plain", "image": "image/jpeg"}
_SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._ ()+-]{0,254}")


class SourceRejected(ValueError):
    """The request cannot be done on this survey; the message says why (HTTP 409/422)."""


def create_source_survey(
    session: Session,
    site: Site,
    *,
    kind: SurveyKind,
    name: str,
    captured_at: datetime,
    options: dict[str, Any] | None = None,
) -> Survey:
    """A new video or image-set survey waiting for its files."""
    if kind not in ROLES_OF_KIND:
        raise InputError(f"a {kind.value} survey is not made from files; upload the DSM instead")
    parsed = ReconstructionOptions.from_dict(options or {})  # unknown keys fail here, clearly
    survey = Survey(
        site=site,
        name=name,
        captured_at=captured_at,
        kind=kind,
        status=SurveyStatus.receiving,
        options=parsed.to_dict() if options else {},
    )
    session.add(survey)
    session.commit()
    return survey


def check_file_name(name: str, role: str) -> str:
    """The name as it will be kept; refuses paths and names that a file system dislikes."""
    if role not in ROLES:
        raise InputError(f"unknown file role {role!r}; roles are {', '.join(ROLES)}")
    if not _SAFE_NAME.fullmatch(name) or ".." in name:
        raise InputError(
            f"file name {name!r} is not accepted: use letters, digits, '.', '_', '-' "
            "and spaces, no folders"
        )
    if not name.lower().endswith(SUFFIXES[role]):
        raise InputError(f"{name}: a {role} file must end with {' or '.join(SUFFIXES[role])}")
    return name


def file_refusal(survey: Survey, role: str, name: str) -> str | None:
    """Why the survey cannot take a file of `role` named `name` now, None if it can.

    A survey takes files while it receives them, and afterwards any file that processing
    has not consumed yet: while processing, the video of a video survey that has none
    (the job reads it as it arrives, or waits for it); once failed, a file of a role it
    lacks (the replacement of one deleted to fix it). A ready survey takes none. The
    answer depends on the survey's rows alone, so two requests racing (an upload
    completing as processing is asked for) get the same answer in either order.
    """
    allowed = ROLES_OF_KIND.get(survey.kind, ())
    if role not in allowed:
        return f"a {survey.kind.value} survey takes {' and '.join(allowed)} files, not {role}"
    has_role = any(f.role == role for f in survey.files)
    if survey.status == SurveyStatus.processing:
        if not (role == "video" and not has_role):
            return (
                f"survey {survey.id} is processing and its {role} files were read when "
                "processing started; wait for it to finish or fail"
            )
    elif survey.status == SurveyStatus.failed:
        if has_role and role != "image":
            return (
                f"survey {survey.id} failed and already has its {role}; to replace it, "
                "delete that file first"
            )
    elif survey.status != SurveyStatus.receiving:
        return f"survey {survey.id} is {survey.status.value}; its files were used to make it"
    for existing in survey.files:
        if existing.name == name:
            return f"survey {survey.id} already has a file named {name!r}"
        if role in ("video", "log") and existing.role == role:
            return f"survey {survey.id} already has a {role} ({existing.name}); delete it first"
    return None


def _check_role(survey: Survey, role: str, name: str) -> None:
    refusal = file_refusal(survey, role, name)
    if refusal is not None:
        raise SourceRejected(refusal)


def check_source_file(
    path: Path,
    role: str,
    name: str,
    *,
    video: VideoClues | None = None,
    recording: int | None = None,
) -> dict[str, Any]:
    """Read the file as the pipeline will; raise InputError naming what is wrong.

    The readers name the file in their messages: they read it through a link named as
    the user's file, not as its storage name. A log is read as processing reads it:
    against the survey's video when there is one (`video`: its length, frame count and
    creation time) and with the survey's chosen `recording`, which pick the recording of
    an SRT joined from several, so the warnings speak of the recording that will be
    used (and a recording the file does not hold is refused, naming those it holds).
    """
    with tempfile.TemporaryDirectory(prefix="slidewatch-check-") as folder:
        link = Path(folder) / name
        link.symlink_to(Path(path).resolve())
        return _read_source_file(link, role, name, video, recording)


def _read_source_file(
    path: Path, role: str, name: str, video: VideoClues | None, recording: int | None
) -> dict[str, Any]:
    if role == "video":
        info = probe_video(path)
        return {
            "duration_s": info.duration_s,
            "width": info.width,
            "height": info.height,
            "clues": VideoClues.from_video_info(info.to_dict()),
        }
    if role == "log":
        log = read_flight_log(path, video=video, recording=recording)
        return {"records": len(log), "format": log.source_format, "warnings": log.warnings}
    meta = read_image_metadata(path)
    if not meta.has_gps:
        raise InputError(
            f"{name}: no GPS position in its EXIF or XMP; slidewatch needs geotagged photos"
        )
    return {"width": meta.width, "height": meta.height}


def _file_of_role(survey: Survey, role: str) -> SurveyFile | None:
    return next((f for f in survey.files if f.role == role), None)


def _video_clues(storage: LocalStorage, survey: Survey) -> VideoClues | None:
    """What the survey's video says of its recording, None while it has none: probed
    again rather than stored, as the job's ingest does."""
    video = _file_of_role(survey, "video")
    if video is None:
        return None
    return VideoClues.from_video_info(probe_video(storage.absolute(video.file.path)).to_dict())


def _chosen_recording(survey: Survey) -> int | None:
    return (survey.options or {}).get("recording")


def _recheck_log(storage: LocalStorage, survey: Survey, video: VideoClues | None) -> None:
    """Read the survey's log again against the video it now has (or no longer has), so
    that its warnings say which recording processing will use.

    A log that the video makes unusable (the matching recording of a joined
    file is unreadable) keeps its place: the video is fine, and the log's warnings say
    why processing will fail with this pair.
    """
    log = _file_of_role(survey, "log")
    if log is None:
        return
    path = storage.absolute(log.file.path)
    try:
        checked = check_source_file(
            path, "log", log.name, video=video, recording=_chosen_recording(survey)
        )
    except InputError as exc:
        against = f"the video ({video.describe()})" if video else "no video"
        log.warnings = [f"{exc} (read against {against}; processing will stop there)"]
        return
    log.warnings = list(checked["warnings"])


def _record(
    session: Session, storage: LocalStorage, survey: Survey, role: str, name: str, saved: SavedFile
) -> SurveyFile:
    try:
        video = _video_clues(storage, survey) if role == "log" else None
        checked = check_source_file(
            storage.absolute(saved.relative_path),
            role,
            name,
            video=video,
            recording=_chosen_recording(survey),
        )
        stored = StoredFile(
            path=saved.relative_path,
            size_bytes=saved.size_bytes,
            sha256=saved.sha256,
            media_type=MEDIA_TYPES[role],
            original_name=name,
        )
        survey_file = SurveyFile(
            survey=survey,
            role=role,
            name=name,
            file=stored,
            warnings=list(checked.get("warnings", [])),
        )
        session.add_all([stored, survey_file])
        if role == "video":
            _recheck_log(storage, survey, checked["clues"])
        session.commit()
    except BaseException:
        session.rollback()
        storage.delete(saved.relative_path)
        raise
    return survey_file


def _folder(survey: Survey) -> str:
    return survey_files_folder(survey.site_id, survey.id)


def add_survey_file(
    session: Session,
    storage: LocalStorage,
    survey: Survey,
    *,
    role: str,
    filename: str,
    source: Path,
) -> SurveyFile:
    """Move a complete file (e.g. a finished resumable upload) into the survey, if it
    takes it now (`file_refusal`)."""
    name = check_file_name(filename, role)
    _check_role(survey, role, name)
    saved = storage.adopt_file(Path(source), _folder(survey), Path(name).suffix.lower())
    return _record(session, storage, survey, role, name, saved)


async def add_survey_file_from_stream(
    session: Session,
    storage: LocalStorage,
    survey: Survey,
    chunks: AsyncIterator[bytes],
    *,
    role: str,
    filename: str,
    max_bytes: int,
) -> SurveyFile:
    """Stream a request body into the survey (raises UploadTooLarge past `max_bytes`)."""
    name = check_file_name(filename, role)
    _check_role(survey, role, name)
    saved = await storage.save_stream(chunks, _folder(survey), Path(name).suffix.lower(), max_bytes)
    return await run_in_threadpool(_record, session, storage, survey, role, name, saved)


def remove_survey_file(
    session: Session, storage: LocalStorage, survey: Survey, file_id: int
) -> None:
    """Delete a file of a survey still receiving files, or of a failed one (to replace
    it: its failed job then starts again from its first stage, which reads the files)."""
    survey_file = session.get(SurveyFile, file_id)
    if survey_file is None or survey_file.survey_id != survey.id:
        raise LookupError(f"survey {survey.id} has no file {file_id}")
    if survey.status not in (SurveyStatus.receiving, SurveyStatus.failed):
        raise SourceRejected(f"survey {survey.id} is {survey.status.value}; its files are in use")
    path = survey_file.file.path
    session.delete(survey_file)
    session.delete(survey_file.file)
    if survey_file.role == "video":
        _recheck_log(storage, survey, None)
    if survey.status == SurveyStatus.failed:
        _restart_failed_jobs(session, survey)
    session.commit()
    storage.delete(path)


def _failed_job(session: Session, survey: Survey) -> Job | None:
    return session.scalar(
        select(Job)
        .where(
            Job.survey_id == survey.id,
            Job.kind == JobKindName.reconstruction,
            Job.state == JobState.failed,
        )
        .order_by(Job.id.desc())
        .limit(1)
    )


def _restart_failed_jobs(session: Session, survey: Survey) -> None:
    """The stages a failed job finished read files that are being replaced: all of them
    run again when it is retried (a retry otherwise keeps finished stages)."""
    job = _failed_job(session, survey)
    if job is None:
        return
    for run in job.stages:
        run.state, run.progress, run.result, run.queued_at = StageState.pending, 0.0, None, None


def missing_files(survey: Survey, arriving: Upload | None = None) -> str | None:
    """What the survey still needs before it can be processed, in plain words (a video
    still `arriving` through a resumable upload counts as there)."""
    roles = [f.role for f in survey.files]
    if arriving is not None and arriving.state == UploadState.receiving:
        roles.append("video")
    if survey.kind == SurveyKind.video:
        needed = [r for r in ("video", "log") if r not in roles]
        if needed:
            return f"survey {survey.id} has no {' and no '.join(needed)} yet"
        return None
    if roles.count("image") < MIN_IMAGES:
        return (
            f"survey {survey.id} has {roles.count('image')} photos; "
            f"at least {MIN_IMAGES} geotagged photos are needed"
        )
    return None


def choose_recording(
    session: Session, storage: LocalStorage, survey: Survey, recording: int
) -> None:
    """Use `recording` (1-based) of the survey's SRT log when it joins several: kept in
    the survey's options, which processing reads, and the log's warnings say so. Raises
    InputError naming the file's recordings when it holds no such one."""
    if survey.status != SurveyStatus.receiving:
        raise SourceRejected(
            f"survey {survey.id} is {survey.status.value}; the recording is chosen before "
            "processing starts"
        )
    log = _file_of_role(survey, "log")
    if log is None:
        raise SourceRejected(f"survey {survey.id} has no flight log to choose a recording of")
    options = ReconstructionOptions.from_dict({**(survey.options or {}), "recording": recording})
    checked = check_source_file(
        storage.absolute(log.file.path),
        "log",
        log.name,
        video=_video_clues(storage, survey),
        recording=options.recording,
    )
    survey.options = {**(survey.options or {}), "recording": recording}
    log.warnings = list(checked["warnings"])
    session.commit()


def submit_reconstruction(celery: Celery, session: Session, survey: Survey) -> Job:
    """Queue the job that reconstructs the survey's DSM from its files (the video may
    still be arriving: see the module doc). A failed survey (fixed, or whose cause is
    gone) is processed again by retrying its failed job: its finished stages are kept
    unless a file was replaced."""
    if survey.status not in (SurveyStatus.receiving, SurveyStatus.failed):
        raise SourceRejected(
            f"survey {survey.id} is {survey.status.value}; only a survey receiving files, "
            "or a failed one, can be processed"
        )
    arriving = arriving_video(session, survey)
    missing = missing_files(survey, arriving)
    if missing:
        raise SourceRejected(missing)
    if arriving is not None and arriving.state == UploadState.receiving:
        arriving.details = {**arriving.details, "streamed": True}
    failed = _failed_job(session, survey) if survey.status == SurveyStatus.failed else None
    if failed is not None:
        retry_job(celery, session, failed)  # sets the survey processing (on_retry)
        return failed
    survey.status = SurveyStatus.processing
    survey.error = None
    job = new_job(survey.site_id, JobKindName.reconstruction, survey_id=survey.id)
    session.add(job)
    session.commit()
    try:
        start_job(celery, session, job)
    except QueueUnavailable as exc:
        survey.status, survey.error = SurveyStatus.failed, str(exc)
        session.commit()
        raise
    return job


def survey_report(storage: LocalStorage, survey: Survey) -> dict[str, Any] | None:
    """The survey's latest reconstruction report (worker/pipeline/reconstruction.py
    `write_report`), None before one exists (a DSM upload never has one)."""
    reports = [p for p in survey.products if p.kind == "report"]
    if not reports:
        return None
    path = storage.absolute(max(reports, key=lambda p: p.id).file.path)
    if not path.is_file():
        return None
    return json.loads(path.read_text(encoding="utf-8"))


def report_quality(report: dict[str, Any] | None) -> dict[str, Any] | None:
    """The report's quality verdict (`{passed, checks}`, worker/pipeline/quality.py), None
    without a report. Reports written before the verdict existed get it from the stage
    results they keep, so an older survey that missed its bounds says so too."""
    if report is None:
        return None
    return report.get("quality") or survey_quality(report.get("stages") or {})


def survey_warnings(survey: Survey, report: dict[str, Any] | None) -> list[str]:
    """What the survey's files and its reconstruction had to warn about, each said once:
    the files' checks first (a log's as read against the survey's video), then the
    reconstruction report's (`survey_report`), which repeats the log's and adds what the
    later stages found and each quality check the survey failed."""
    warnings = [w for f in survey.files for w in f.warnings]
    if report is not None:
        # The job hands the library links named as uploaded: the report names the
        # files as the user knows them.
        warnings += report.get("warnings", [])
        quality = report_quality(report)
        if quality is not None:
            warnings += failed_messages(quality)
    return list(dict.fromkeys(warnings))


def uploaded_file_warnings(session: Session, upload: Upload) -> list[str]:
    """The warnings of the survey file a complete resumable upload became, as they read
    now (a log's are read again when its video arrives); none for a DSM's upload."""
    if upload.purpose != "survey_file" or upload.state != UploadState.complete:
        return []
    found = session.scalar(
        select(SurveyFile).where(
            SurveyFile.survey_id == upload.survey_id, SurveyFile.name == upload.filename
        )
    )
    return list(found.warnings) if found else []
