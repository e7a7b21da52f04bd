"""Queue job stages on the broker (used by the API, the tasks and the recovery sweep)."""

from datetime import UTC, datetime

from celery import Celery
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import StageRun
from worker.celery_app import QUEUE, RUN_STAGE_TASK


def dispatch_stage(celery: Celery, session: Session, job_id: int, stage: str) -> None:
    """Send the message that runs `stage` of job `job_id`, and record when it was sent.

    The caller commits `session`. Sending first and recording after means a crash in
    between can only cause a duplicate message, which the runner's claim makes harmless.
    """
    celery.send_task(RUN_STAGE_TASK, args=[job_id, stage], queue=QUEUE)
    run = session.scalar(select(StageRun).where(StageRun.job_id == job_id, StageRun.stage == stage))
    if run is not None:
        run.queued_at = datetime.now(UTC)
