"""Celery tasks of monitoring: alert deliveries, report building and the schedule tick."""

import logging

from celery import Task

from backend.config import get_settings
from backend.db.session import get_sessionmaker, session_scope
from backend.services import alerts, reports, schedules
from backend.storage import LocalStorage
from worker.celery_app import BUILD_REPORT_TASK, DELIVER_TASK, MONITORING_TICK_TASK, QUEUE, app

log = logging.getLogger(__name__)


def _storage() -> LocalStorage:
    return LocalStorage(get_settings().storage_dir)


@app.task(bind=True, name=DELIVER_TASK)
def deliver(self: Task, delivery_id: int) -> None:
    """One attempt of a webhook call or e-mail; failed attempts come back with backoff."""
    outcome = alerts.attempt_delivery(delivery_id, get_sessionmaker(), _storage())
    if outcome.retry_in_s is not None:
        raise self.retry(countdown=outcome.retry_in_s, max_retries=None)


@app.task(name=BUILD_REPORT_TASK)
def build_report(report_id: int) -> None:
    reports.build(report_id, get_sessionmaker(), _storage())


@app.task(name=MONITORING_TICK_TASK)
def monitoring_tick() -> dict[str, int]:
    """Run due schedules; queue again deliveries and reports whose task was lost."""
    with get_sessionmaker()() as session:
        runs = schedules.claim_due_runs(session)
    for run in runs:
        log.info("schedule %s of site %s: report %s", run.schedule_id, run.site_id, run.report_id)
        app.send_task(BUILD_REPORT_TASK, args=[run.report_id], queue=QUEUE)
    with session_scope() as session:
        overdue = alerts.overdue_deliveries(session)
        lost = reports.lost_reports(session)
    for delivery_id in overdue:
        app.send_task(DELIVER_TASK, args=[delivery_id], queue=QUEUE)
    for report_id in lost:
        app.send_task(BUILD_REPORT_TASK, args=[report_id], queue=QUEUE)
    return {"schedules": len(runs), "deliveries": len(overdue), "reports": len(lost)}
