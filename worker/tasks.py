"""Celery tasks: thin adapters that run job stages and the recovery sweep.

This module is the worker's composition root: the settings are read here, once, into the
process's JobContext that the stage runner and the job kinds are given.
"""

import logging
from datetime import UTC, datetime, timedelta
from functools import lru_cache

from celery import Task
from celery.signals import worker_init, worker_ready

from backend.config import get_settings
from backend.db.session import get_sessionmaker
from backend.wiring import wire
from worker.celery_app import RECOVER_TASK, RUN_STAGE_TASK, app
from worker.dispatch import dispatch_stage
from worker.jobs.context import JobContext
from worker.jobs.recovery import stalled_stages
from worker.jobs.runner import execute_stage, fail_job, record_retry

log = logging.getLogger(__name__)


@lru_cache(maxsize=1)
def job_context() -> JobContext:
    """The worker process's context (its settings, storage and session factory)."""
    return JobContext.from_settings(get_settings(), get_sessionmaker())


def retry_delay_s(retries: int) -> float:
    """Exponential backoff: 2, 4, 8, ... seconds, at most 5 minutes."""
    return float(min(2 ** (retries + 1), 300))


@app.task(bind=True, name=RUN_STAGE_TASK)
def run_stage(self: Task, job_id: int, stage: str) -> None:
    context = job_context()
    settings = context.settings
    claimed: list[int] = []  # the attempt this task claimed, if it got that far
    try:
        next_stage = execute_stage(context, job_id, stage, on_claim=claimed.append)
    except Exception as exc:
        # Fenced by the claim: a failure of an attempt that another worker took over (this
        # one was stalled past the stale threshold) neither retries nor fails the stage.
        attempt = claimed[0] if claimed else None
        reason = f"{type(exc).__name__}: {exc}"
        if self.request.retries >= settings.task_max_retries:
            log.exception("stage %s of job %s failed for good", stage, job_id)
            attempts = self.request.retries + 1
            reason = f"failed after {attempts} attempts: {reason}"
            fail_job(context, job_id, stage, reason, attempt)
            return
        delay = retry_delay_s(self.request.retries)
        log.warning(
            "stage %s of job %s failed (%s); retrying in %.0f s", stage, job_id, reason, delay
        )
        if not record_retry(context, job_id, stage, reason, delay, attempt):
            return
        raise self.retry(exc=exc, countdown=delay, max_retries=settings.task_max_retries) from exc
    if next_stage is not None:
        with context.session_scope() as session:
            dispatch_stage(app, session, job_id, next_stage)


def sent_at(request_expires: object, expires_after_s: float) -> datetime | None:
    """When a sweep's message was sent: Celery's messages carry no time sent, but the sweep
    is always sent to expire `expires_after_s` later (beat's schedule, `_recover_on_start`)."""
    if not request_expires:
        return None
    expires = (
        request_expires
        if isinstance(request_expires, datetime)
        else datetime.fromisoformat(str(request_expires))
    )
    expires = expires if expires.tzinfo else expires.replace(tzinfo=UTC)
    return expires - timedelta(seconds=expires_after_s)


@app.task(bind=True, name=RECOVER_TASK)
def recover_stalled_jobs(self: Task) -> int:
    """Queue again every stage whose worker or message was lost; return how many."""
    context = job_context()
    with context.session_scope() as session:
        stalled = stalled_stages(
            session,
            context.settings.stale_stage_after_s,
            requeue_waiting_after_s=context.settings.requeue_waiting_after_s,
            queue_passed_at=sent_at(self.request.expires, context.settings.recovery_interval_s),
        )
        for job_id, stage in stalled:
            log.warning("requeueing stalled stage %s of job %s", stage, job_id)
            dispatch_stage(app, session, job_id, stage)
    return len(stalled)


@worker_init.connect
def _wire(**_kwargs: object) -> None:
    settings = job_context().settings
    wire(settings)
    if settings.broker_is_embedded:
        # kombu polls the SQLite broker at its transport class's interval: the broker's
        # transport options all go to SQLAlchemy's create_engine, which refuses others.
        from kombu.transport import sqlalchemy as sqlite_broker

        sqlite_broker.Transport.polling_interval = settings.broker_polling_interval_s


@worker_ready.connect
def _recover_on_start(**_kwargs: object) -> None:
    # A killed worker's message comes back late or never: Redis delivers it again only
    # after the visibility timeout, the embedded broker not at all. A worker that starts
    # (often the killed one's replacement) sweeps at once, besides beat's regular sweep.
    recover_stalled_jobs.apply_async(expires=job_context().settings.recovery_interval_s)
