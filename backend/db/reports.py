"""What a report shows, read from the database, and the files of a built report recorded.

The report job (worker/jobs/report.py) gathers a report's data here (`gather`: plain
values and file paths for the report library, worker/reports) and records what it built
(`store_files`); the service (backend/services/reports.py) uses `latest_comparison` to
refuse a report that could not be made. It sits with the domain, below the services, as
the job layer imports no service.
"""

from __future__ import annotations

from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from shapely.geometry import shape
from sqlalchemy import select
from sqlalchemy.orm import Session, aliased

from backend.db.detections import detection_model
from backend.db.models import Comparison, JobState, Report, Site, Survey
from backend.db.stored_files import record_stored_file
from backend.storage import LocalStorage
from backend.storage_layout import report_file
from worker.reports import Change, DetectionRow, ReportData
from worker.reports.i18n import Catalogue, catalogue

MEDIA_TYPES = {"pdf": "application/pdf", "html": "text/html; charset=utf-8"}
FILES = {"pdf": "report.pdf", "html": "report.html"}


class ReportRejected(ValueError):
    """A report that cannot be made; the message says why."""


def utcnow() -> datetime:
    return datetime.now(UTC)


def _aware(moment: datetime | None) -> datetime | None:
    if moment is None:
        return None
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def latest_comparison(session: Session, site_id: int) -> Comparison | None:
    post = aliased(Survey)
    return session.scalar(
        select(Comparison)
        .join(post, Comparison.post_survey_id == post.id)
        .where(Comparison.site_id == site_id, Comparison.status == JobState.succeeded)
        .order_by(post.captured_at.desc(), Comparison.id.desc())
        .limit(1)
    )


def model_version(method: str, model: str | None = None, words: Catalogue | None = None) -> str:
    """What made the report's figures: the software, the detection method and its model."""

    def of(package: str) -> str:
        try:
            return version(package)
        except PackageNotFoundError:
            return "unknown"

    words = words or catalogue()
    made_by = {"slidewatch": of("slidewatch"), "method": method, "xdem": of("xdem")}
    if model:
        return words.text("report.made_by_model", model=model, **made_by)
    return words.text("report.made_by", **made_by)


def report_language(report: Report, site: Site) -> str:
    """The language a report is written in: the one it was asked in, else its site's."""
    return report.language or site.language


def _survey_label(survey: Survey, timezone: str, words: Catalogue) -> str:
    return words.text(
        "report.survey",
        survey=survey.id,
        name=survey.name,
        captured=words.time(survey.captured_at, timezone),
    )


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


def _product_path(storage: LocalStorage, comparison: Comparison, kind: str) -> Path:
    product = next((p for p in comparison.products if p.kind == kind), None)
    if product is None:
        raise ReportRejected(f"comparison {comparison.id} has no {kind} product")
    return storage.absolute(product.file.path)


def gather(session: Session, storage: LocalStorage, report: Report) -> ReportData:
    """Everything the report shows, in its language; ReportRejected when it cannot be made."""
    site = session.get(Site, report.site_id)
    language = report_language(report, site)
    words = catalogue(language)
    comparison = (
        session.get(Comparison, report.comparison_id)
        if report.comparison_id is not None
        else latest_comparison(session, report.site_id)
    )
    if comparison is None or comparison.status != JobState.succeeded:
        raise ReportRejected(f"site {site.id} has no finished comparison to report on")
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
            words.text("report.newer_survey", survey=_survey_label(newest, site.timezone, words))
        )
    data = ReportData(
        report_id=report.id,
        site_name=site.name,
        created_at=_aware(report.created_at) or utcnow(),
        trigger=report.trigger,
        comparison_id=comparison.id,
        pre_survey=_survey_label(comparison.pre_survey, site.timezone, words),
        post_survey=_survey_label(post, site.timezone, words),
        dh_path=_product_path(storage, comparison, "dh"),
        dsm_path=_product_path(storage, comparison, "post_coregistered"),
        detections=rows,
        change=None,
        parameters=dict(comparison.parameters or {}),
        processing=_processing(comparison),
        model_version=model_version(
            comparison.method,
            detection_model(comparison, (comparison.summary or {}).get("stages") or {}),
            words,
        ),
        notes=notes,
        timezone=site.timezone,
        language=language,
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


def store_files(
    session: Session,
    storage: LocalStorage,
    report: Report,
    comparison_id: int,
    totals: dict[str, Any],
    language: str,
) -> None:
    """Record the built files, the totals and the language they are written in; idempotent
    (a stage stored again updates)."""
    for kind, name in FILES.items():
        relative = report_file(report.site_id, report.id, name)
        stored = record_stored_file(session, storage, relative, MEDIA_TYPES[kind])
        setattr(report, f"{kind}_file_id", stored.id)
    report.comparison_id = comparison_id
    report.language = language
    report.summary = {"comparison_id": comparison_id, **totals}
