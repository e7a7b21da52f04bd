"""Real worker processes against real brokers and databases."""

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.config import Settings
from backend.db.tokens import create_token
from tests.databases import migrate_new_database

# Short liveness timings, so that a killed worker's stage is taken over within seconds.
FAST_RECOVERY = {
    "SLIDEWATCH_HEARTBEAT_INTERVAL_S": "0.5",
    "SLIDEWATCH_STALE_STAGE_AFTER_S": "3",
    "SLIDEWATCH_RECOVERY_INTERVAL_S": "2",
    "SLIDEWATCH_BROKER_VISIBILITY_TIMEOUT_S": "5",
    # The embedded broker hands out one task per poll: with the default 1 s, each stage
    # (and each recovery sweep queued between them) waits up to a second to start.
    "SLIDEWATCH_BROKER_POLLING_INTERVAL_S": "0.1",
}


class SlidewatchProcess:
    """A `slidewatch` command in its own process group, so that it can be SIGKILLed whole."""

    def __init__(self, settings: Settings, log_path: Path, args: list[str], ready: bytes) -> None:
        self.env = {
            **os.environ,
            **FAST_RECOVERY,
            "SLIDEWATCH_DATA_DIR": str(settings.data_dir),
            "SLIDEWATCH_DATABASE_URL": settings.resolved_database_url,
            "SLIDEWATCH_BROKER_URL": settings.resolved_broker_url,
            "SLIDEWATCH_DETECTION_METHOD_MODULES": json.dumps(settings.detection_method_modules),
        }
        self.log_path = log_path
        self.args = args
        self.ready = ready
        self.process: subprocess.Popen | None = None

    def start(self) -> "SlidewatchProcess":
        return self.launch().wait_ready()

    def launch(self) -> "SlidewatchProcess":
        """Start the process without waiting for it, so that several start at once."""
        command = [sys.executable, "-m", "backend.cli", *self.args]
        self._log = open(self.log_path, "ab")  # noqa: SIM115 (open while the worker lives)
        self.process = subprocess.Popen(
            command,
            env=self.env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        return self

    def wait_ready(self) -> "SlidewatchProcess":
        assert self.process is not None
        deadline = time.monotonic() + 60
        while self.ready not in self.log_path.read_bytes():
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"{self.args} did not start:\n{self.log()}")
            time.sleep(0.05)
        return self

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-6000:]

    def kill(self) -> None:
        assert self.process is not None
        os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait()
        self._log.close()

    def stop(self) -> None:
        """End the process once the test is done with it. Nothing is checked about how it
        ends, and a Celery warm shutdown spends 4-6 s in its polling loop and pool threads:
        the whole process group is killed at once, as `kill` does."""
        if self.process and self.process.poll() is None:
            self.kill()


@pytest.fixture
def start_worker(tmp_path: Path) -> Iterator[Callable[..., SlidewatchProcess]]:
    """Start `slidewatch worker`; with beat, as deployed: `--beat` on the embedded default
    (as `slidewatch run` does), a separate `slidewatch beat` process otherwise."""
    started: list[SlidewatchProcess] = []

    def start(settings: Settings, beat: bool = True) -> SlidewatchProcess:
        args = ["worker"]
        launched = []
        if beat and settings.broker_is_embedded:
            args.append("--beat")
        elif beat and not any(p.args == ["beat"] for p in started):
            beat_log = tmp_path / "beat.log"
            launched.append(SlidewatchProcess(settings, beat_log, ["beat"], b"beat: Starting"))
        worker = SlidewatchProcess(settings, tmp_path / "worker.log", args, b" ready.")
        launched.append(worker)
        # Beat and worker start side by side (each takes seconds to import).
        for process in launched:
            started.append(process.launch())
        for process in launched:
            process.wait_ready()
        return worker

    yield start
    for process in reversed(started):
        process.stop()


@pytest.fixture
def redis_postgres_settings(tmp_path: Path, postgres_url: str, redis_url: str) -> Settings:
    return Settings(data_dir=tmp_path / "data", database_url=postgres_url, broker_url=redis_url)


def api_client(settings: Settings) -> tuple[TestClient, dict[str, str]]:
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    migrate_new_database(settings.resolved_database_url)
    app = create_app(settings)
    with app.state.sessionmaker() as session:
        token = create_token(session, "integration tests")
        session.commit()
    return TestClient(app), {"Authorization": f"Bearer {token}"}


def upload_dsm_pair(
    client: TestClient, auth: dict, pre: Path, post: Path, site_name: str = "integration"
) -> tuple[int, list[int]]:
    """A new site with the two DSMs as its June and July surveys: (site id, survey ids)."""
    site = client.post("/api/v1/sites", json={"name": site_name}, headers=auth).json()["id"]
    ids = []
    for path, when in ((pre, "2026-06-01T10:00:00Z"), (post, "2026-07-01T10:00:00Z")):
        response = client.post(
            f"/api/v1/sites/{site}/surveys",
            params={"captured_at": when},
            content=path.read_bytes(),
            headers={**auth, "Content-Type": "image/tiff"},
        )
        assert response.status_code == 201, response.text
        ids.append(response.json()["id"])
    return site, ids


def wait_for_job(
    client: TestClient, auth: dict, site_id: int, job_id: int, until: Callable[[dict], bool],
    timeout_s: float = 180,
) -> dict:  # fmt: skip
    deadline = time.monotonic() + timeout_s
    while True:
        job = client.get(f"/api/v1/sites/{site_id}/jobs/{job_id}", headers=auth).json()
        if until(job):
            return job
        if time.monotonic() > deadline:
            raise AssertionError(f"job did not get there in {timeout_s} s: {job}")
        time.sleep(0.1)
