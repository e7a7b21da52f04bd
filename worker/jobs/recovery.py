"""Find stages whose message or worker was lost, so that they can be queued again.

Queuing a stage twice is harmless: the runner's claim lets one copy run it and drops the
others, so the sweep errs on the side of requeueing.
"""

from datetime import UTC, datetime, timedelta

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import Job, JobState, StageState


def stalled_stages(
    session: Session, stale_after_s: float, now: datetime | None = None
) -> list[tuple[int, str]]:
    """(job id, stage) of every unfinished job whose current stage shows no life."""
    now = now or datetime.now(UTC)
    cutoff = now - timedelta(seconds=stale_after_s)
    stalled = []
    jobs = session.scalars(select(Job).where(Job.state.in_([JobState.queued, JobState.running])))
    for job in jobs:
        current = next((r for r in job.stages if r.state != StageState.succeeded), None)
        if current is None or current.state == StageState.failed:
            continue
        if current.state == StageState.running:
            alive_at = current.heartbeat_at
        else:
            alive_at = current.queued_at
        if alive_at is None or _aware(alive_at) < cutoff:
            stalled.append((job.id, current.stage))
    return stalled


def _aware(moment: datetime) -> datetime:
    # SQLite returns naive datetimes for timezone-aware columns; they are stored in UTC.
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)
