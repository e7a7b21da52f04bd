"""Monitoring schedules: a cron expression per site; each time it names, a report.

Beat sends a "tick" task every SLIDEWATCH_SCHEDULE_TICK_S seconds; the tick claims each
due schedule with one conditional UPDATE that moves its `next_run_at` on
(`... WHERE id = :id AND next_run_at = :seen`), and only the claimer creates the run's
report. A second beat, a restarted beat, or two ticks at once therefore never run a
schedule twice; the report's unique (schedule_id, scheduled_for) is a second guard. Runs
missed while nothing ticked are not made up: the next run is computed from now, so a
schedule that was due (once or many times) runs once.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import UTC, datetime
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from croniter import CroniterError, croniter
from sqlalchemy import select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from backend.db.models import JobState, Report, Schedule

log = logging.getLogger(__name__)


class ScheduleRejected(ValueError):
    """A cron expression or time zone that cannot be used; the message says why."""


def utcnow() -> datetime:
    return datetime.now(UTC)


def _aware(moment: datetime) -> datetime:
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def check(cron: str, timezone: str) -> None:
    try:
        ZoneInfo(timezone)
    except (ZoneInfoNotFoundError, ValueError):
        raise ScheduleRejected(f"unknown time zone {timezone!r}; e.g. UTC, Europe/Rome") from None
    if len(cron.split()) != 5 or not croniter.is_valid(cron):
        raise ScheduleRejected(
            f"invalid cron expression {cron!r}: five fields, minute hour day-of-month month "
            "day-of-week, e.g. '0 6 * * 1' for Mondays at 06:00"
        )
    try:
        next_run(cron, timezone, utcnow())
    except CroniterError:
        # e.g. '0 0 30 2 *': valid fields, but no day they name exists.
        raise ScheduleRejected(
            f"cron expression {cron!r} never fires: no date has the day and month it names"
        ) from None


def next_run(cron: str, timezone: str, after: datetime) -> datetime:
    """The first time after `after` that `cron` names in `timezone`, in UTC."""
    local = _aware(after).astimezone(ZoneInfo(timezone))
    return croniter(cron, local).get_next(datetime).astimezone(UTC)


def next_runs(cron: str, timezone: str, after: datetime, count: int) -> list[datetime]:
    """The next `count` times after `after` that `cron` names in `timezone`, in UTC."""
    local = _aware(after).astimezone(ZoneInfo(timezone))
    times = croniter(cron, local)
    return [times.get_next(datetime).astimezone(UTC) for _ in range(count)]


@dataclass(frozen=True)
class ClaimedRun:
    schedule_id: int
    site_id: int
    scheduled_for: datetime
    report_id: int


def claim_due_runs(session: Session, now: datetime | None = None) -> list[ClaimedRun]:
    """Claim every due schedule, create its run's report, commit; return what was claimed."""
    now = now or utcnow()
    due = session.execute(
        select(
            Schedule.id, Schedule.site_id, Schedule.next_run_at, Schedule.cron, Schedule.timezone
        )
        .where(Schedule.enabled.is_(True), Schedule.next_run_at <= now)
        .order_by(Schedule.next_run_at)
    ).all()
    claimed: list[ClaimedRun] = []
    for schedule_id, site_id, seen, cron, timezone in due:
        try:
            following = next_run(cron, timezone, max(now, _aware(seen)))
        except CroniterError:
            # Saved before such expressions were refused: it can never run again.
            log.warning("schedule %s: cron %r never fires; disabled", schedule_id, cron)
            session.execute(
                update(Schedule).where(Schedule.id == schedule_id).values(enabled=False)
            )
            session.commit()
            continue
        moved = session.execute(
            update(Schedule)
            .where(Schedule.id == schedule_id, Schedule.next_run_at == seen)
            .values(next_run_at=following, last_run_at=seen)
            .execution_options(synchronize_session=False)
        )
        if moved.rowcount != 1:
            session.rollback()
            continue  # another tick claimed it
        report = Report(
            site_id=site_id,
            schedule_id=schedule_id,
            scheduled_for=_aware(seen),
            trigger="schedule",
            status=JobState.queued,
        )
        session.add(report)
        try:
            session.commit()
        except IntegrityError:
            session.rollback()
            continue
        claimed.append(ClaimedRun(schedule_id, site_id, _aware(seen), report.id))
    return claimed
