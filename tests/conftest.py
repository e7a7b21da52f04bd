"""Fixtures shared by the whole suite: real databases, real brokers, real files."""

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import redis

from backend.config import Settings
from tests.databases import empty_postgres_database


def _redis_url_of_this_process() -> str:
    """The test Redis; each pytest-xdist process on its own database (gw0 on 1, gw1 on 2…),
    since a test empties its database before and after it runs."""
    url = os.environ.get("SLIDEWATCH_TEST_REDIS_URL", "redis://127.0.0.1:6379/0")
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw"):
        return url
    return f"{url.rsplit('/', 1)[0]}/{int(worker[2:]) + 1}"


TEST_REDIS_URL = _redis_url_of_this_process()

# Tiles are not rendered ahead in the tests' workers (tests/integration/test_tile_prerender.py
# turns it on for its own): thousands of tiles after each survey and comparison would take
# the CPU from the tests running beside them, and no other test reads them.
os.environ.setdefault("SLIDEWATCH_TILE_PRERENDER_MAX_TILES", "0")


@pytest.fixture
def postgres_url() -> Iterator[str]:
    """A new empty database on the test PostgreSQL server, dropped afterwards."""
    with empty_postgres_database() as url:
        yield url


@pytest.fixture
def redis_url() -> Iterator[str]:
    """The test Redis, emptied before and after the test."""
    client = redis.Redis.from_url(TEST_REDIS_URL)
    client.flushdb()
    try:
        yield TEST_REDIS_URL
    finally:
        client.flushdb()
        client.close()


@pytest.fixture(scope="session")
def simulated_mounds_survey(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A short simulated survey of the paper's mound field: (flight folder, truth folder).

    6 s of 640x360 video at 15 fps from 7 m with its DJI SRT and AirData CSV (stand-alone
    GPS) and the orthoimage it was rendered from, made once per test session and shared by
    the reconstruction and API tests.
    """
    from worker.simulator.simulate import SimulationOptions, simulate_scenario

    out = tmp_path_factory.mktemp("sim")
    options = SimulationOptions(
        steps=1,
        video_seconds=6.0,
        fps=15.0,
        registration=False,
        workers=1,
        seed=3,
    )
    simulate_scenario("paper-mounds", out, options)
    return out / "step1" / "flight1", out / "step1" / "truth"


@pytest.fixture
def embedded_settings(tmp_path: Path) -> Settings:
    """The embedded default: SQLite database and SQLite broker in a fresh data directory."""
    return Settings(data_dir=tmp_path / "data")


@pytest.fixture
def sqlite_url(tmp_path: Path) -> str:
    return f"sqlite:///{tmp_path / 'slidewatch.db'}"
