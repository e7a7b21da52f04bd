"""The demo site of the first start: simulated flights enter the real pipeline as uploads
would, and their DSMs are compared once both are ready."""

from pathlib import Path

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from backend.db.models import Job, Survey, SurveyStatus
from backend.services.demo import (
    DEMO_SITE_NAME,
    DemoOptions,
    compare_when_ready,
    seed_demo,
    start_demo,
)
from tests.api_helpers import upload_dsm
from worker.pipeline.comparison import default_method
from worker.simulator.dsm_pair import DsmPairPaths


def test_flights_become_video_surveys_with_queued_reconstructions(
    app: FastAPI, simulated_mounds_survey: tuple[Path, Path], tmp_path: Path
) -> None:
    flight, _truth = simulated_mounds_survey
    storage, celery = app.state.storage, app.state.celery
    with app.state.sessionmaker() as session:
        from datetime import UTC, datetime

        site, surveys = start_demo(
            session, storage, celery, [flight, flight], first_flown_at=datetime.now(UTC)
        )
        assert site.name == DEMO_SITE_NAME and site.timezone == "Asia/Tokyo"
        assert [s.status for s in surveys] == [SurveyStatus.processing] * 2
        assert [sorted(f.role for f in s.files) for s in surveys] == [["log", "video"]] * 2
        assert surveys[0].captured_at < surveys[1].captured_at
        jobs = session.scalars(select(Job).order_by(Job.id)).all()
        assert [(j.kind, j.survey_id) for j in jobs] == [
            ("reconstruction", surveys[0].id),
            ("reconstruction", surveys[1].id),
        ]
        # The simulator's own files stay where they are: the surveys hold copies.
        assert (flight / "DJI_0001.MP4").exists() and (flight / "DJI_0001.SRT").exists()
        # Seeded once: a second start finds the site and simulates nothing.
        assert seed_demo(session, storage, celery, tmp_path / "never-used") is None
        assert not (tmp_path / "never-used").exists()


def test_the_pair_is_compared_once_both_dsms_are_ready(
    app: FastAPI, client: TestClient, auth: dict, dsm_pair_files: DsmPairPaths
) -> None:
    site_id = client.post("/api/v1/sites", json={"name": "demo"}, headers=auth).json()["id"]
    pre = upload_dsm(client, auth, site_id, dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site_id, dsm_pair_files.post, "2026-06-02T10:00:00Z")
    with app.state.sessionmaker() as session:
        surveys = [session.get(Survey, pre["id"]), session.get(Survey, post["id"])]
        site = surveys[0].site
        comparison = compare_when_ready(
            session, app.state.celery, site, surveys, DemoOptions(poll_s=0)
        )
        assert comparison is not None
        assert (comparison.pre_survey_id, comparison.post_survey_id) == (pre["id"], post["id"])
        assert comparison.method == default_method()
        # A reconstruction that failed leaves the pair uncompared, and says so in the log.
        surveys[1].status = SurveyStatus.failed
        session.commit()
        waited: list[float] = []
        assert (
            compare_when_ready(
                session, app.state.celery, site, surveys, DemoOptions(), sleep=waited.append
            )
            is None
        )
        assert waited == []
