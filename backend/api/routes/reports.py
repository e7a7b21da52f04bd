"""Reports of a site: on demand or from schedules; PDF and HTML downloads.

A report is built by a job (kind "report"): `job_id` names it, for its stage, progress
and event stream under `/sites/{site}/jobs/{job_id}`.
"""

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, status
from fastapi.responses import FileResponse
from sqlalchemy import select

from backend.api.access import SiteAnalyst, SiteViewer
from backend.api.deps import CeleryDep, SessionDep, StorageDep, owned_by_site
from backend.api.schemas_monitoring import ReportCreate, ReportOut
from backend.db.models import Report, StoredFile
from backend.ids import RowId
from backend.services.reports import ReportRejected, request_report, shown_status
from backend.urls import api_url
from worker.reports.i18n import UnknownLanguage, check_language

router = APIRouter(prefix="/sites/{site_id}/reports", tags=["reports"])


def report_out(report: Report) -> ReportOut:
    base = api_url("sites", report.site_id, "reports", report.id)
    return ReportOut(
        id=report.id,
        site_id=report.site_id,
        schedule_id=report.schedule_id,
        scheduled_for=report.scheduled_for,
        comparison_id=report.comparison_id,
        trigger=report.trigger,
        language=report.language,
        status=shown_status(report),
        job_id=report.job.id if report.job else None,
        summary=report.summary,
        error=report.error,
        created_at=report.created_at,
        finished_at=report.finished_at,
        pdf_url=f"{base}/pdf" if report.pdf_file_id else None,
        html_url=f"{base}/html" if report.html_file_id else None,
    )


@router.post("", response_model=ReportOut, status_code=status.HTTP_202_ACCEPTED)
def create_report(
    body: ReportCreate,
    site: SiteAnalyst,
    session: SessionDep,
    celery: CeleryDep,
    lang: Annotated[
        str | None,
        Query(max_length=16, description="The language to write it in, as `language` says."),
    ] = None,
) -> ReportOut:
    """Queue a report of a comparison (default: the site's latest) in a language (default:
    the site's); answers at once."""
    language = body.language or lang
    if language is not None:
        try:
            check_language(language)
        except UnknownLanguage as exc:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    try:
        # If the broker is down, the job stays queued and the recovery sweep queues it.
        report = request_report(celery, session, site, body.comparison_id, language)
    except ReportRejected as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    return report_out(report)


@router.get("", response_model=list[ReportOut])
def list_reports(site: SiteViewer, session: SessionDep) -> list[ReportOut]:
    query = select(Report).where(Report.site_id == site.id).order_by(Report.id.desc())
    return [report_out(r) for r in session.scalars(query)]


@router.get("/{report_id}", response_model=ReportOut)
def get_report(report_id: RowId, site: SiteViewer, session: SessionDep) -> ReportOut:
    return report_out(owned_by_site(session, Report, site, report_id, "report"))


def _download(
    session: SessionDep, storage: StorageDep, report: Report, file_id: int | None, kind: str
) -> FileResponse:
    stored = session.get(StoredFile, file_id) if file_id else None
    if stored is None or not storage.absolute(stored.path).is_file():
        raise HTTPException(
            status.HTTP_404_NOT_FOUND, f"report {report.id} has no {kind} (it is {report.status})"
        )
    return FileResponse(
        storage.absolute(stored.path),
        media_type=stored.media_type,
        filename=f"slidewatch-report-{report.id}.{kind}",
        content_disposition_type="inline",
    )


@router.get("/{report_id}/pdf", response_class=FileResponse, summary="The report as PDF")
def report_pdf(
    report_id: RowId, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> FileResponse:
    report = owned_by_site(session, Report, site, report_id, "report")
    return _download(session, storage, report, report.pdf_file_id, "pdf")


@router.get("/{report_id}/html", response_class=FileResponse, summary="The report as HTML")
def report_html(
    report_id: RowId, site: SiteViewer, session: SessionDep, storage: StorageDep
) -> FileResponse:
    report = owned_by_site(session, Report, site, report_id, "report")
    return _download(session, storage, report, report.html_file_id, "html")
