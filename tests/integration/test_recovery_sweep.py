"""The recovery sweep queues again what was lost, once, and leaves waiting stages alone."""

from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from sqlalchemy.orm import Session

from backend.db.models import Job, JobState, StageRun, StageState
from backend.db.session import make_engine
from tests.databases import migrate_new_database
from worker.jobs.recovery import stalled_stages

NOW = datetime(2026, 11, 26, 12, 0, tzinfo=UTC)


def ago(seconds: float) -> datetime:
    return NOW - timedelta(seconds=seconds)


@pytest.fixture
def session(tmp_path: Path) -> Iterator[Session]:
    url = f"sqlite:///{tmp_path / 'sweep.db'}"
    migrate_new_database(url)
    with Session(make_engine(url)) as session:
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
