"""Reports of a site: requested on demand or by a schedule, built by a job.

A report covers one finished comparison: the one asked for, else the site's latest (by
the later survey's capture time). A scheduled run does not start comparisons: when the
site has a newer survey than that comparison, the report says so.

A report is built by a job of kind "report" (worker/jobs/report.py) with one stage,
"build", run by the same stage runner as comparisons: retries with backoff, heartbeats,
stall recovery and the job's event stream apply to reports too. The job's hooks keep the
report's own status (queued, succeeded, failed) for its users; while the job runs, the
report shows as running. The stage writes the files atomically under
`reports/{site}/{report}/`; storing them records them (backend/db/reports.py), and a
finished report alerts (`report_ready`: webhooks, and e-mail with the PDF attached).
"""

from __future__ import annotations

from celery import Celery
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from backend.db.models import Comparison, Job, JobState, Report, Site
from backend.db.reports import ReportRejected, latest_comparison
from worker.jobs.control import JobKindName, new_job, start_job

__all__ = ["ReportRejected", "queue_waiting_reports", "request_report", "shown_status"]


def request_report(
    celery: Celery,
    session: Session,
    site: Site,
    comparison_id: int | None,
    language: str | None = None,
) -> Report:
    """A queued on-demand report and its job (committed, first stage queued), written in
    `language` (a catalogue's code, checked by the caller), else in the site's.

    Nobody waits on a report at once: if the broker cannot be reached, the job stays
    queued and the recovery sweep queues it later.
    """
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
        site_id=site.id,
        comparison_id=comparison_id,
        trigger="on_demand",
        language=language or site.language,
        status=JobState.queued,
    )
    session.add(report)
    session.flush()
    job = new_job(site.id, JobKindName.report, report_id=report.id)
    session.add(job)
    session.commit()
    start_job(celery, session, job, recover_later=True)
    return report


def queue_waiting_reports(celery: Celery, session: Session) -> list[int]:
    """Give every unfinished report that has no job yet its job, and queue it; return the
    reports' ids.

    The monitoring tick creates scheduled reports (backend/services/schedules.py), then
    calls this: a tick that died in between leaves its report to the next tick. Two ticks
    at once cannot both create a job for one report (jobs.report_id is unique).
    """
    waiting = session.scalars(
        select(Report)
        .outerjoin(Job, Job.report_id == Report.id)
        .where(Report.status.in_([JobState.queued, JobState.running]), Job.id.is_(None))
        .order_by(Report.id)
    ).all()
    queued = []
    for report in waiting:
        job = new_job(report.site_id, JobKindName.report, report_id=report.id)
        session.add(job)
        try:
            session.commit()
        except IntegrityError:
            session.rollback()  # another tick made it
            continue
        start_job(celery, session, job, recover_later=True)
        queued.append(report.id)
    return queued


def shown_status(report: Report) -> JobState:
    """The report's status as its users see it: running while its job runs."""
    if report.status == JobState.queued and report.job and report.job.state == JobState.running:
        return JobState.running
    return report.status
