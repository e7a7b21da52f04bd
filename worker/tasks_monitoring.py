"""Celery tasks of monitoring: alert deliveries and the schedule tick.

Reports are jobs (worker/jobs/report.py): their stage runs as any job's, and the jobs'
recovery sweep (worker/tasks.py) queues again a report whose build was lost.
"""

import logging

from celery import Task

from backend.config import get_settings
from backend.db.session import get_sessionmaker, session_scope
from backend.services import alerts, reports, schedules
from backend.storage import LocalStorage
from worker.celery_app import DELIVER_TASK, MONITORING_TICK_TASK, QUEUE, app

log = logging.getLogger(__name__)


@app.task(bind=True, name=DELIVER_TASK)
def deliver(self: Task, delivery_id: int) -> None:
    """One attempt of a webhook call or e-mail; failed attempts come back with backoff."""
    settings = get_settings()
    outcome = alerts.attempt_delivery(
        delivery_id, get_sessionmaker(), LocalStorage(settings.storage_dir), settings
    )
    if outcome.retry_in_s is not None:
        raise self.retry(countdown=outcome.retry_in_s, max_retries=None)


@app.task(name=MONITORING_TICK_TASK)
def monitoring_tick() -> dict[str, int]:
    """Run due schedules (each makes a report, built by its job); queue again deliveries
    whose task was lost."""
    with get_sessionmaker()() as session:
        runs = schedules.claim_due_runs(session)
        for run in runs:
            log.info(
                "schedule %s of site %s: report %s", run.schedule_id, run.site_id, run.report_id
            )
        # The claimed runs' reports, and any left without a job by a tick that died.
        queued = reports.queue_waiting_reports(app, session)
    with session_scope() as session:
        overdue = alerts.overdue_deliveries(session, get_settings())
    for delivery_id in overdue:
        app.send_task(DELIVER_TASK, args=[delivery_id], queue=QUEUE)
    return {"schedules": len(runs), "deliveries": len(overdue), "reports": len(queued)}
