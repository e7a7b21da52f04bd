"""GIS tests run on both databases: the embedded SQLite and PostgreSQL."""

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.config import Settings
from tests.monitoring_helpers import app_for, token_for
from worker.simulator.dsm_pair import DsmPairPaths, make_dsm_pair, write_dsm_pair


@pytest.fixture(params=["sqlite", "postgresql"])
def gis_settings(request: pytest.FixtureRequest, tmp_path: Path) -> Settings:
    if request.param == "sqlite":
        return Settings(data_dir=tmp_path / "data")
    return Settings(
        data_dir=tmp_path / "data", database_url=request.getfixturevalue("postgres_url")
    )


@pytest.fixture
def sqlite_settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data")


@pytest.fixture
def gis_app(gis_settings: Settings, monkeypatch: pytest.MonkeyPatch) -> Iterator[FastAPI]:
    with app_for(gis_settings, monkeypatch) as app:
        yield app


@pytest.fixture
def embedded_app(sqlite_settings: Settings, monkeypatch: pytest.MonkeyPatch) -> Iterator[FastAPI]:
    with app_for(sqlite_settings, monkeypatch) as app:
        yield app


@pytest.fixture
def token(gis_app: FastAPI) -> str:
    return token_for(gis_app)


@pytest.fixture
def client(gis_app: FastAPI) -> Iterator[TestClient]:
    with TestClient(gis_app) as test_client:
        yield test_client


@pytest.fixture
def auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture(scope="session")
def gis_pair(tmp_path_factory: pytest.TempPathFactory) -> DsmPairPaths:
    pair = make_dsm_pair(shape=(240, 240), pixel_size_m=1.0, shift_m=(1.3, -0.7, 0.2), seed=7)
    return write_dsm_pair(pair, tmp_path_factory.mktemp("gis-pair"))
