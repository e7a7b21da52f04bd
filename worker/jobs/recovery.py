"""Find stages whose message or worker was lost, so that they can be queued again.

Queuing a stage twice is harmless: the runner's claim lets one copy run it and drops the
others, so the sweep errs on the side of requeueing. It runs every few seconds (beat's
`recover-stalled-jobs`, on whichever worker is free; and when a worker starts), so it must
not flood the queue either:

- A *running* stage whose heartbeat stopped lost its worker: queued again at once, and
  then not again until `requeue_waiting_after_s`, however long it waits for a free worker.
- A *pending* stage may simply be waiting behind others in the queue. The queue is first in,
  first out (Redis lists, the embedded broker's messages by time sent), so when the sweep's
  own message is being run, every message sent before it has been taken by a worker, which
  claims its stage at once: a stage still pending whose message was sent before the sweep's
  (`queue_passed_at`) lost it with the worker that took it (a worker killed just as it took
  it; Redis hands a message over before the worker records it as unacknowledged). Without
  that moment, or as a fallback, a message `requeue_waiting_after_s` old counts as lost; a
  stage never queued is queued at once.
"""

from datetime import UTC, datetime, timedelta

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import Job, JobState, StageState

# A worker claims a stage within milliseconds of taking its message; a stage whose message
# went before the sweep's by less than this may still be on its way to its claim.
CLAIM_MARGIN_S = 1.0


def stalled_stages(
    session: Session,
    stale_after_s: float,
    now: datetime | None = None,
    requeue_waiting_after_s: float | None = None,
    queue_passed_at: datetime | None = None,
) -> list[tuple[int, str]]:
    """(job id, stage) of every unfinished job whose current stage shows no life.

    `requeue_waiting_after_s`: how old a queued message may be before it is taken to be
    lost (default: `stale_after_s`). `queue_passed_at`: when the message now being run (the
    sweep's) was sent; every message sent before it has been taken by a worker."""
    now = now or datetime.now(UTC)
    stale = now - timedelta(seconds=stale_after_s)
    waited = now - timedelta(seconds=requeue_waiting_after_s or stale_after_s)
    if queue_passed_at is not None:
        waited = max(waited, queue_passed_at - timedelta(seconds=CLAIM_MARGIN_S))
    stalled = []
    jobs = session.scalars(select(Job).where(Job.state.in_([JobState.queued, JobState.running])))
    for job in jobs:
        current = next((r for r in job.stages if r.state != StageState.succeeded), None)
        if current is None or current.state == StageState.failed:
            continue
        queued_at = _aware(current.queued_at) if current.queued_at else None
        if current.state == StageState.running:
            beat = _aware(current.heartbeat_at) if current.heartbeat_at else None
            if beat is not None and beat >= stale:
                continue  # alive
            requeued_since = queued_at is not None and beat is not None and queued_at > beat
            if not requeued_since or queued_at < waited:
                stalled.append((job.id, current.stage))
        elif queued_at is None or queued_at < waited:
            stalled.append((job.id, current.stage))
    return stalled


def _aware(moment: datetime) -> datetime:
    # SQLite returns naive datetimes for timezone-aware columns; they are stored in UTC.
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)
