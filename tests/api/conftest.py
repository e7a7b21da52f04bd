"""An app on the embedded default (SQLite file, SQLite broker, local files) per test."""

from collections.abc import Iterator

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.config import Settings, get_settings
from backend.db import session as db_session
from backend.db.tokens import create_token
from tests.databases import migrate_new_database
from worker.simulator.dsm_pair import DsmPairPaths, make_dsm_pair, write_dsm_pair


@pytest.fixture
def app(embedded_settings: Settings, monkeypatch: pytest.MonkeyPatch) -> Iterator[FastAPI]:
    # The worker-side code reads the settings from the environment: point it here too.
    monkeypatch.setenv("SLIDEWATCH_DATA_DIR", str(embedded_settings.data_dir))
    for cached in (get_settings, db_session.get_engine, db_session.get_sessionmaker):
        cached.cache_clear()
    embedded_settings.data_dir.mkdir(parents=True)
    migrate_new_database(embedded_settings.resolved_database_url)
    application = create_app(embedded_settings)
    yield application
    application.state.engine.dispose()
    db_session.get_engine().dispose()
    for cached in (get_settings, db_session.get_engine, db_session.get_sessionmaker):
        cached.cache_clear()


@pytest.fixture
def client(app: FastAPI) -> Iterator[TestClient]:
    with TestClient(app) as test_client:
        yield test_client


@pytest.fixture
def auth(app: FastAPI) -> dict[str, str]:
    with app.state.sessionmaker() as session:
        token = create_token(session, "tests")
        session.commit()
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture(scope="session")
def dsm_pair_files(tmp_path_factory: pytest.TempPathFactory) -> DsmPairPaths:
    """A small pre/post pair with a planted landslide and a 1.3 m × 0.7 m shift."""
    pair = make_dsm_pair(shape=(240, 240), pixel_size_m=1.0, shift_m=(1.3, -0.7, 0.2), seed=7)
    return write_dsm_pair(pair, tmp_path_factory.mktemp("dsm-pair"))
