"""One app for the whole fuzzing run, on PostgreSQL (whose integer columns are what ids
beyond their range break), with rows to find: a site with surveys, comparisons and
detections, a DSM with its COG product, a user, a schedule and a webhook."""

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi import FastAPI

from backend.config import Settings
from backend.db.models import Schedule, Webhook
from backend.services.users import create_user
from tests.api_helpers import upload_dsm
from tests.databases import empty_postgres_database
from tests.monitoring_helpers import app_for, seed_detections, token_for
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair


@pytest.fixture(scope="module")
def fuzz_database() -> Iterator[str]:
    with empty_postgres_database() as url:
        yield url


@pytest.fixture(scope="module")
def fuzz_app(tmp_path_factory: pytest.TempPathFactory, fuzz_database: str) -> Iterator[FastAPI]:
    root = tmp_path_factory.mktemp("fuzz")
    settings = Settings(data_dir=root / "data", database_url=fuzz_database)
    with pytest.MonkeyPatch.context() as monkeypatch, app_for(settings, monkeypatch) as app:
        _seed(app, root)
        yield app


@pytest.fixture(scope="module")
def fuzz_auth(fuzz_app: FastAPI) -> dict[str, str]:
    """An administrator's API token: every route is open to it, so every route is reached."""
    return {"Authorization": f"Bearer {token_for(fuzz_app)}"}


def _seed(app: FastAPI, root: Path) -> None:
    from fastapi.testclient import TestClient

    ids = seed_detections(app)
    pair = write_dsm_pair(make_dsm_pair(shape=(64, 64), pixel_size_m=1.0, seed=3), root / "pair")
    auth = {"Authorization": f"Bearer {token_for(app)}"}
    with TestClient(app) as client:
        upload_dsm(client, auth, ids["site"], pair.pre, "2026-09-01T10:00:00Z")
    with app.state.sessionmaker() as session:
        create_user(session, "maria", "landslide-2026", "Maria Rossi")
        session.add(Schedule(site_id=ids["site"], cron="0 6 * * 1", timezone="UTC",
                             next_run_at=_monday()))  # fmt: skip
        session.add(Webhook(site_id=ids["site"], url="https://hooks.example/slidewatch",
                            secret="whsec_fuzz", events=["job_failed"]))  # fmt: skip
        session.commit()


def _monday():
    from datetime import UTC, datetime

    return datetime(2026, 12, 7, 6, tzinfo=UTC)
