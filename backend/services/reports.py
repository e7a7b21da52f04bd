"""Reports of a site: requested on demand or by a schedule, built by a worker task.

A report covers one finished comparison: the one asked for, else the site's latest (by
the later survey's capture time). A scheduled run does not start comparisons: when the
site has a survey newer than that comparison, the report says so. Building is claimed
with a conditional UPDATE (queued -> running, or running but stale), writes its files
atomically under `reports/{site}/{report}/`, then records them and alerts
(`report_ready`: webhooks, and e-mail with the PDF attached).
"""

from __future__ import annotations

import logging
from datetime import UTC, datetime, timedelta
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from shapely.geometry import shape
from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session, aliased

from backend.db.models import Comparison, JobState, Report, Site, StoredFile, Survey
from backend.services import alerts
from backend.services.comparisons import detection_model, stage_results
from backend.storage import LocalStorage, file_digest
from worker.reports import Change, DetectionRow, ReportData, build_report

log = logging.getLogger(__name__)

STALE_BUILD_AFTER = timedelta(minutes=15)
LOST_QUEUED_AFTER = timedelta(minutes=5)
MEDIA_TYPES = {"pdf": "application/pdf", "html": "text/html; charset=utf-8"}


class ReportRejected(ValueError):
    """A report that cannot be made; the message says why."""


def utcnow() -> datetime:
    return datetime.now(UTC)


def _aware(moment: datetime | None) -> datetime | None:
    if moment is None:
        return None
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def report_folder(site_id: int, report_id: int) -> str:
    return f"reports/{site_id}/{report_id}"


def latest_comparison(session: Session, site_id: int) -> Comparison | None:
    post = aliased(Survey)
    return session.scalar(
        select(Comparison)
        .join(post, Comparison.post_survey_id == post.id)
        .where(Comparison.site_id == site_id, Comparison.status == JobState.succeeded)
        .order_by(post.captured_at.desc(), Comparison.id.desc())
        .limit(1)
    )


def request_report(session: Session, site: Site, comparison_id: int | None) -> Report:
    """A queued on-demand report (committed); the caller queues its task."""
    if comparison_id is not None:
        comparison = session.get(Comparison, comparison_id)
        if comparison is None or comparison.site_id != site.id:
            raise ReportRejected(f"comparison {comparison_id} not found in site {site.id}")
        if comparison.status != JobState.succeeded:
            raise ReportRejected(
                f"comparison {comparison_id} is {comparison.status}; a report needs a finished one"
            )
    elif latest_comparison(session, site.id) is None:
        raise ReportRejected(f"site {site.id} has no finished comparison to report on yet")
    report = Report(
        site_id=site.id, comparison_id=comparison_id, trigger="on_demand", status=JobState.queued
    )
    session.add(report)
    session.commit()
    return report


def claim_build(session: Session, report_id: int, now: datetime | None = None) -> bool:
    now = now or utcnow()
    claimed = session.execute(
        update(Report)
        .where(
            Report.id == report_id,
            or_(
                Report.status == JobState.queued,
                (Report.status == JobState.running) & (Report.started_at < now - STALE_BUILD_AFTER),
            ),
        )
        .values(status=JobState.running, started_at=now, error=None)
        .execution_options(synchronize_session=False)
    )
    session.commit()
    return claimed.rowcount == 1


def lost_reports(session: Session, now: datetime | None = None) -> list[int]:
    """Reports whose task was lost: queued for long, or running with no end in sight."""
    now = now or utcnow()
    return list(
        session.scalars(
            select(Report.id).where(
                or_(
                    (Report.status == JobState.queued)
                    & (Report.created_at < now - LOST_QUEUED_AFTER),
                    (Report.status == JobState.running)
                    & (Report.started_at < now - STALE_BUILD_AFTER),
                )
            )
        )
    )


def model_version(method: str, detection_model: str | None = None) -> str:
    def of(package: str) -> str:
        try:
            return version(package)
        except PackageNotFoundError:
            return "unknown"

    model = f" (model {detection_model})" if detection_model else ""
    return f"slidewatch {of('slidewatch')}, detection method '{method}'{model}, xdem {of('xdem')}"


def _survey_label(survey: Survey) -> str:
    return f"survey {survey.id} '{survey.name}' ({_aware(survey.captured_at):%Y-%m-%d %H:%M} UTC)"


def _processing(comparison: Comparison) -> dict[str, Any]:
    stages = (comparison.summary or {}).get("stages", {})
    kept: dict[str, Any] = {}
    for stage, result in stages.items():
        scalars = {
            k: v
            for k, v in (result or {}).items()
            if isinstance(v, int | float | str)
            and not isinstance(v, bool)
            and not k.endswith("seconds")
        }
        if scalars:
            kept[stage] = scalars
    return kept


def _product_path(storage: LocalStorage, comparison: Comparison, kind: str):
    product = next((p for p in comparison.products if p.kind == kind), None)
    if product is None:
        raise ReportRejected(f"comparison {comparison.id} has no {kind} product")
    return storage.absolute(product.file.path)


def gather(session: Session, storage: LocalStorage, report: Report) -> ReportData:
    site = session.get(Site, report.site_id)
    comparison = (
        session.get(Comparison, report.comparison_id)
        if report.comparison_id is not None
        else latest_comparison(session, report.site_id)
    )
    if comparison is None or comparison.status != JobState.succeeded:
        raise ReportRejected(f"site {site.id} has no finished comparison to report on")
    report.comparison_id = comparison.id
    rows = []
    for number, detection in enumerate(comparison.detections, start=1):
        centroid = shape(detection.geometry).centroid
        rows.append(
            DetectionRow(
                number=number,
                id=detection.id,
                area_m2=detection.area_m2,
                volume_loss_m3=detection.volume_loss_m3,
                volume_gain_m3=detection.volume_gain_m3,
                max_abs_dh_m=detection.max_abs_dh_m,
                centroid_lat=centroid.y,
                centroid_lon=centroid.x,
                score=detection.score,
                geometry=detection.geometry,
            )
        )
    notes = []
    newest = session.scalar(
        select(Survey)
        .where(Survey.site_id == site.id)
        .order_by(Survey.captured_at.desc(), Survey.id.desc())
        .limit(1)
    )
    post = comparison.post_survey
    if newest is not None and _aware(newest.captured_at) > _aware(post.captured_at):
        notes.append(
            f"The site has a newer survey ({_survey_label(newest)}) that no finished "
            "comparison covers yet: compare it to include it."
        )
    data = ReportData(
        report_id=report.id,
        site_name=site.name,
        created_at=_aware(report.created_at) or utcnow(),
        trigger=report.trigger,
        comparison_id=comparison.id,
        pre_survey=_survey_label(comparison.pre_survey),
        post_survey=_survey_label(post),
        dh_path=_product_path(storage, comparison, "dh"),
        dsm_path=_product_path(storage, comparison, "post_coregistered"),
        detections=rows,
        change=None,
        parameters=dict(comparison.parameters or {}),
        processing=_processing(comparison),
        model_version=model_version(
            comparison.method, detection_model(comparison, stage_results(comparison, None))
        ),
        notes=notes,
    )
    data.change = _change(session, report, comparison.id, data.totals)
    return data


def _change(
    session: Session, report: Report, comparison_id: int, totals: dict[str, float]
) -> Change | None:
    previous = session.scalar(
        select(Report)
        .where(
            Report.site_id == report.site_id,
            Report.status == JobState.succeeded,
            Report.id < report.id,
        )
        .order_by(Report.id.desc())
        .limit(1)
    )
    if previous is None or not previous.summary:
        return Change(None, None, False, 0, 0.0, 0.0, 0.0)
    before = previous.summary
    return Change(
        previous_report_id=previous.id,
        previous_created_at=_aware(previous.created_at),
        same_comparison=before.get("comparison_id") == comparison_id,
        detections=int(totals["detections"] - before.get("detections", 0)),
        total_area_m2=totals["total_area_m2"] - before.get("total_area_m2", 0.0),
        total_volume_loss_m3=totals["total_volume_loss_m3"]
        - before.get("total_volume_loss_m3", 0.0),
        total_volume_gain_m3=totals["total_volume_gain_m3"]
        - before.get("total_volume_gain_m3", 0.0),
    )


def _store(session: Session, storage: LocalStorage, relative: str, media_type: str) -> StoredFile:
    size, sha256 = file_digest(storage.absolute(relative))
    stored = session.scalar(select(StoredFile).where(StoredFile.path == relative))
    if stored is None:
        stored = StoredFile(path=relative, size_bytes=size, sha256=sha256, media_type=media_type)
        session.add(stored)
        session.flush()
    else:
        stored.size_bytes, stored.sha256, stored.media_type = size, sha256, media_type
    return stored


def build(report_id: int, session_factory, storage: LocalStorage) -> bool:
    """Build a claimed report's files and record them; False if it was not ours to build."""
    with session_factory() as session:
        if not claim_build(session, report_id):
            return False
        report = session.get(Report, report_id)
        try:
            data = gather(session, storage, report)
            folder = report_folder(report.site_id, report.id)
            build_report(data, storage.absolute(folder))
            report.pdf_file_id = _store(
                session, storage, f"{folder}/report.pdf", MEDIA_TYPES["pdf"]
            ).id
            report.html_file_id = _store(
                session, storage, f"{folder}/report.html", MEDIA_TYPES["html"]
            ).id
            report.summary = {"comparison_id": data.comparison_id, **data.totals}
            report.status = JobState.succeeded
            report.error = None
            report.finished_at = utcnow()
            session.flush()
            alerts.guarded(alerts.report_ready, session, report)
            session.commit()
        except Exception as exc:
            session.rollback()
            log.exception("report %s failed", report_id)
            report = session.get(Report, report_id)
            report.status = JobState.failed
            report.error = (
                str(exc) if isinstance(exc, ReportRejected) else f"{type(exc).__name__}: {exc}"
            )
            report.finished_at = utcnow()
            session.commit()
    return True
