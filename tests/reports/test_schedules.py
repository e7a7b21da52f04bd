"""Monitoring schedules: a due schedule is claimed once, however many ticks see it, and a
schedule set a few seconds ahead makes exactly one report through real beat and worker
processes, even with two beats running."""

import threading
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from backend.config import Settings
from backend.db.migrate import upgrade
from backend.db.models import Report, Schedule, Site
from backend.db.session import make_engine
from backend.services.schedules import claim_due_runs, next_run
from tests.integration.conftest import SlidewatchProcess
from tests.monitoring_helpers import app_for, finished_comparison, token_for, wait_until
from tests.reports.test_reports import pdf_text
from worker.simulator.dsm_pair import DsmPairPaths


def _schedule(sessionmaker, due_at: datetime) -> int:
    with sessionmaker() as session:
        site = Site(name="ticked")
        session.add(site)
        session.flush()
        schedule = Schedule(site_id=site.id, cron="0 6 * * 1", timezone="UTC", next_run_at=due_at)
        session.add(schedule)
        session.commit()
        return schedule.id


@pytest.mark.parametrize("database", ["sqlite", "postgresql"])
def test_due_schedule_is_claimed_once_by_concurrent_ticks(
    database: str, request: pytest.FixtureRequest
) -> None:
    url = request.getfixturevalue("sqlite_url" if database == "sqlite" else "postgres_url")
    upgrade(url)
    engine = make_engine(url)
    try:
        from sqlalchemy.orm import sessionmaker

        factory = sessionmaker(bind=engine, expire_on_commit=False)
        due = datetime(2026, 6, 1, 6, 0, tzinfo=UTC)
        schedule_id = _schedule(factory, due)
        now = due + timedelta(days=9)  # missed runs are not made up: it runs once
        claimed: list = []
        barrier = threading.Barrier(4)

        def tick() -> None:
            barrier.wait()
            with factory() as session:
                claimed.extend(claim_due_runs(session, now))

        threads = [threading.Thread(target=tick) for _ in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=30)
        assert [run.schedule_id for run in claimed] == [schedule_id]
        with factory() as session:
            assert session.scalar(select(func.count()).select_from(Report)) == 1
            schedule = session.get(Schedule, schedule_id)
            expected = next_run("0 6 * * 1", "UTC", now)
            assert schedule.next_run_at.replace(tzinfo=UTC) == expected
            assert expected == datetime(2026, 6, 15, 6, 0, tzinfo=UTC)  # the next Monday
            assert claim_due_runs(session, now) == []
    finally:
        engine.dispose()


def test_next_run_follows_the_schedule_time_zone() -> None:
    after = datetime(2026, 3, 28, 12, 0, tzinfo=UTC)  # Europe/Rome moves to summer time
    assert next_run("0 6 * * *", "Europe/Rome", after) == datetime(2026, 3, 29, 4, 0, tzinfo=UTC)


@pytest.mark.integration
def test_schedule_makes_exactly_one_report_through_real_beat_and_worker(
    tmp_path: Path,
    postgres_url: str,
    redis_url: str,
    report_pair: DsmPairPaths,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    settings = Settings(
        data_dir=tmp_path / "data",
        database_url=postgres_url,
        broker_url=redis_url,
        schedule_tick_s=0.5,
    )
    processes: list[SlidewatchProcess] = []
    with app_for(settings, monkeypatch) as app, TestClient(app) as client:
        auth = {"Authorization": f"Bearer {token_for(app)}"}
        ids = finished_comparison(client, auth, report_pair, name="Scheduled slope")
        site = ids["site"]
        try:
            # One worker, and two beats at once (as after a botched restart): both tick.
            processes.append(
                SlidewatchProcess(settings, tmp_path / "worker.log", ["worker"], b" ready.")
            )
            for n in (1, 2):
                beat_settings = settings.model_copy(update={"data_dir": tmp_path / f"beat{n}"})
                beat_settings.data_dir.mkdir()
                processes.append(
                    SlidewatchProcess(
                        beat_settings, tmp_path / f"beat{n}.log", ["beat"], b"beat: Starting"
                    )
                )
            for process in processes:  # side by side: each takes seconds to import
                process.launch()
            for process in processes:
                process.wait_ready()
            due = datetime.now(UTC) + timedelta(seconds=3)
            created = client.post(
                f"/api/v1/sites/{site}/schedules",
                json={"cron": "0 6 * * 1", "next_run_at": due.isoformat(), "name": "weekly"},
                headers=auth,
            )
            assert created.status_code == 201, created.text

            def finished_reports() -> list[dict]:
                listed = client.get(f"/api/v1/sites/{site}/reports", headers=auth).json()
                return [r for r in listed if r["status"] in ("succeeded", "failed")]

            [report] = wait_until(finished_reports, timeout_s=60)
            # Several more ticks of both beats pass: still exactly one report.
            wait_until(lambda: datetime.now(UTC) > due + timedelta(seconds=3), timeout_s=10)
            listed = client.get(f"/api/v1/sites/{site}/reports", headers=auth).json()
        finally:
            for process in reversed(processes):
                process.stop()
            logs = "\n".join(p.log() for p in processes)
        assert len(listed) == 1, logs
        assert report["status"] == "succeeded", (report["error"], logs)
        assert report["trigger"] == "schedule" and report["schedule_id"] == created.json()["id"]
        schedule = client.get(
            f"/api/v1/sites/{site}/schedules/{created.json()['id']}", headers=auth
        )
        next_at = datetime.fromisoformat(schedule.json()["next_run_at"].replace("Z", "+00:00"))
        assert next_at.weekday() == 0 and (next_at.hour, next_at.minute) == (6, 0)

        [landslide] = client.get(
            f"/api/v1/sites/{site}/comparisons/{ids['comparison']}/detections", headers=auth
        ).json()["features"]
        text = pdf_text(client.get(report["pdf_url"], headers=auth).content)
        props = landslide["properties"]
        assert "Landslide monitoring report: Scheduled slope" in text and "scheduled" in text
        assert f"{props['area_m2']:,.1f}" in text and f"{props['volume_loss_m3']:,.1f}" in text
        assert f"{props['max_abs_dh_m']:.2f}" in text
