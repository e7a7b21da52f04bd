"""The recovery sweep queues again what was lost, once, and leaves waiting stages alone; a
stage's claim is fenced, so that an attempt taken over cannot touch the one running now."""

from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from sqlalchemy import select, update
from sqlalchemy.orm import Session

from backend.config import Settings
from backend.db.models import Job, JobState, StageRun, StageState
from backend.db.session import make_engine
from tests.databases import migrate_new_database
from worker.jobs.context import JobContext
from worker.jobs.recovery import stalled_stages
from worker.jobs.runner import _claim, fail_job, record_retry

NOW = datetime(2026, 11, 26, 12, 0, tzinfo=UTC)


def ago(seconds: float) -> datetime:
    return NOW - timedelta(seconds=seconds)


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    settings = Settings(data_dir=tmp_path / "data")
    settings.data_dir.mkdir(parents=True)
    migrate_new_database(settings.resolved_database_url)
    return settings


@pytest.fixture
def session(settings: Settings) -> Iterator[Session]:
    with Session(make_engine(settings.resolved_database_url)) as session:
        yield session


def job(session: Session, state: StageState, **stage: datetime | None) -> int:
    run = StageRun(stage="train", position=0, state=state, progress=0.0, attempts=1, **stage)
    row = Job(site_id=None, kind="training", state=JobState.running, stages=[run])
    session.add(row)
    session.flush()
    return row.id


def test_a_dead_workers_stage_is_queued_again_once(session: Session) -> None:
    alive = job(session, StageState.running, queued_at=ago(60), heartbeat_at=ago(3))
    dead = job(session, StageState.running, queued_at=ago(60), heartbeat_at=ago(9))
    requeued = job(session, StageState.running, queued_at=ago(1), heartbeat_at=ago(9))
    long_ago = job(session, StageState.running, queued_at=ago(400), heartbeat_at=ago(500))
    found = {j for j, _ in stalled_stages(session, 8, NOW, requeue_waiting_after_s=300)}
    assert alive not in found and requeued not in found
    assert {dead, long_ago} <= found


def test_a_waiting_stage_is_queued_again_only_once_its_message_is_lost(session: Session) -> None:
    waiting = job(session, StageState.pending, queued_at=ago(60))
    never_sent = job(session, StageState.pending, queued_at=None)
    retry_later = job(session, StageState.pending, queued_at=NOW + timedelta(seconds=30))
    found = {j for j, _ in stalled_stages(session, 8, NOW, requeue_waiting_after_s=300)}
    assert found == {never_sent}
    # The sweep's own message, sent 10 s ago, is being run: the queue went past the message
    # sent 60 s ago, which a worker took and never claimed: it was lost with that worker.
    passed = stalled_stages(session, 8, NOW, 300, queue_passed_at=ago(10))
    assert {j for j, _ in passed} == {waiting, never_sent}
    assert retry_later not in {j for j, _ in passed}
    # A message sent just before the sweep's may still be on its way to its claim.
    assert waiting not in {j for j, _ in stalled_stages(session, 8, NOW, 300, ago(59.5))}


def test_an_attempt_taken_over_cannot_retry_or_fail_the_one_running_now(
    settings: Settings, session: Session
) -> None:
    job_id = job(session, StageState.running, queued_at=ago(60), heartbeat_at=ago(3))
    session.commit()
    run = session.scalar(select(StageRun).where(StageRun.job_id == job_id))
    # The claim is judged at the clock the heartbeats were written by (NOW, not the day's).
    assert _claim(session, run.id, NOW, 8) is None  # alive: nobody takes it
    session.execute(update(StageRun).values(heartbeat_at=ago(9)))
    assert _claim(session, run.id, NOW, 8) == 2  # its worker is dead: attempt 2 takes it
    session.commit()

    context = JobContext.from_settings(settings)
    # Attempt 1 was only stalled, and now fails: neither a retry nor a failure is recorded.
    assert not record_retry(context, job_id, "train", "boom", 2.0, attempt=1)
    fail_job(context, job_id, "train", "boom", attempt=1)
    session.expire_all()
    run, owner = session.get(StageRun, run.id), session.get(Job, job_id)
    assert (run.state, run.attempts, owner.state) == (
        StageState.running, 2, JobState.running
    )  # fmt: skip
    # The attempt running now may fail as any does.
    assert record_retry(context, job_id, "train", "boom", 2.0, attempt=2)
    session.expire_all()
    assert session.get(StageRun, run.id).state == StageState.pending
