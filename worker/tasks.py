"""Celery tasks: thin adapters that run job stages and the recovery sweep."""

import logging

from celery import Task
from celery.signals import worker_ready

from backend.config import get_settings
from backend.db.session import session_scope
from worker.celery_app import RECOVER_TASK, RUN_STAGE_TASK, app
from worker.dispatch import dispatch_stage
from worker.jobs.recovery import stalled_stages
from worker.jobs.runner import execute_stage, fail_job, record_retry

log = logging.getLogger(__name__)


def retry_delay_s(retries: int) -> float:
    """Exponential backoff: 2, 4, 8, ... seconds, at most 5 minutes."""
    return float(min(2 ** (retries + 1), 300))


@app.task(bind=True, name=RUN_STAGE_TASK)
def run_stage(self: Task, job_id: int, stage: str) -> None:
    settings = get_settings()
    try:
        next_stage = execute_stage(job_id, stage)
    except Exception as exc:
        reason = f"{type(exc).__name__}: {exc}"
        if self.request.retries >= settings.task_max_retries:
            log.exception("stage %s of job %s failed for good", stage, job_id)
            fail_job(job_id, stage, f"failed after {self.request.retries + 1} attempts: {reason}")
            return
        delay = retry_delay_s(self.request.retries)
        log.warning(
            "stage %s of job %s failed (%s); retrying in %.0f s", stage, job_id, reason, delay
        )
        record_retry(job_id, stage, reason, delay)
        raise self.retry(exc=exc, countdown=delay, max_retries=settings.task_max_retries) from exc
    if next_stage is not None:
        with session_scope() as session:
            dispatch_stage(app, session, job_id, next_stage)


@app.task(name=RECOVER_TASK)
def recover_stalled_jobs() -> int:
    """Queue again every stage whose worker or message was lost; return how many."""
    with session_scope() as session:
        stalled = stalled_stages(session, get_settings().stale_stage_after_s)
        for job_id, stage in stalled:
            log.warning("requeueing stalled stage %s of job %s", stage, job_id)
            dispatch_stage(app, session, job_id, stage)
    return len(stalled)


@worker_ready.connect
def _recover_on_start(**_kwargs: object) -> None:
    # The embedded broker does not redeliver a message taken by a worker that was killed:
    # sweep at start-up, so that a restarted worker picks such jobs up again.
    if get_settings().broker_is_embedded:
        recover_stalled_jobs.delay()
