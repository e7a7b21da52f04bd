"""Killed workers are replaced and their stage runs again within 15 s; stopping stops all.

Real processes, real brokers and databases, the recovery settings' defaults (heartbeat,
stale threshold, sweep interval, the embedded broker's polling): what a deployment gets.
The busy stage is the `linger` test method's (tests/plugins/slow_method.py), busy for a
set time in a temporary folder of its own, so that the kill lands in it for certain.
"""

import http.client
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.config import Settings
from tests.databases import migrate_new_database
from tests.integration.conftest import (
    FAST_RECOVERY,
    SlidewatchProcess,
    api_client,
    upload_dsm_pair,
    wait_for_job,
)
from worker.pipeline.detection_methods import method_names, unregister_method
from worker.simulator.dsm_pair import DsmPairPaths, make_dsm_pair, write_dsm_pair

pytestmark = pytest.mark.integration
SLOW_MODULE = "tests.plugins.slow_method"
RECOVERY_TARGET_S = 15.0


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> DsmPairPaths:
    dsm_pair = make_dsm_pair(shape=(200, 200), pixel_size_m=0.5, shift_m=(0.4, 0.2, 0.1), seed=5)
    return write_dsm_pair(dsm_pair, tmp_path_factory.mktemp("pair"))


@pytest.fixture(params=["redis+postgresql", "embedded"])
def settings(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Settings]:
    """Both brokers, with the slow test method registered (here and in the workers)."""
    assert "linger" not in method_names()
    if request.param == "redis+postgresql":
        base = request.getfixturevalue("redis_postgres_settings")
    else:
        base = Settings(data_dir=tmp_path / "data")
    yield base.model_copy(update={"detection_method_modules": [SLOW_MODULE]})
    unregister_method("linger")
    sys.modules.pop(SLOW_MODULE, None)


def children_of(pid: int) -> list[int]:
    """The processes whose parent is `pid` (from /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue  # gone meanwhile
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


def descendants_of(pid: int) -> list[int]:
    found = []
    for child in children_of(pid):
        found += [child, *descendants_of(child)]
    return found


def command_line(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has exited; only its parent's wait is missing


def celery_worker_pid(supervisor: SlidewatchProcess) -> int:
    assert supervisor.process is not None
    workers = [
        pid for pid in children_of(supervisor.process.pid) if " worker " in command_line(pid)
    ]
    assert len(workers) == 1, workers
    return workers[0]


class Workers:
    """`slidewatch worker` (and beat) with the deployment's default recovery timings."""

    def __init__(self, settings: Settings, tmp_path: Path) -> None:
        self.settings = settings
        self.tmp_path = tmp_path
        self.started: list[SlidewatchProcess] = []

    def start(self) -> SlidewatchProcess:
        args = ["worker"]
        launched = []
        if self.settings.broker_is_embedded:
            args.append("--beat")  # as `slidewatch run` does
        else:
            launched.append(self._process(["beat"], "beat.log", b"beat: Starting"))
        worker = self._process(args, "worker.log", b" ready.")
        launched.append(worker)
        for process in launched:
            self.started.append(process.launch())
        for process in launched:
            process.wait_ready()
        return worker

    def _process(self, args: list[str], log: str, ready: bytes) -> SlidewatchProcess:
        process = SlidewatchProcess(self.settings, self.tmp_path / log, args, ready)
        for name in FAST_RECOVERY:
            process.env.pop(name, None)
        return process

    def stop(self) -> None:
        for process in reversed(self.started):
            process.stop()


@pytest.fixture
def workers(settings: Settings, tmp_path: Path) -> Iterator[Workers]:
    started = Workers(settings, tmp_path)
    yield started
    started.stop()


def queue_linger(
    client: TestClient, auth: dict, site: int, surveys: list[int], seconds: float
) -> tuple[int, int]:
    """A comparison of the site's two surveys with the linger method: (job, comparison)."""
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={
            "pre_survey_id": surveys[0],
            "post_survey_id": surveys[1],
            "method": "linger",
            "parameters": {"linger": {"seconds": seconds}},
        },
        headers=auth,
    )
    assert created.status_code == 202, created.text
    job = created.json()["job"]
    return job["id"], job["comparison_id"]


def finished(job: dict) -> bool:
    return job["state"] in ("succeeded", "failed")


@pytest.mark.alone  # 15 s includes a worker's start, which a second test process slows
def test_killed_workers_are_replaced_and_their_stage_runs_again_within_15_s(
    settings: Settings, workers: Workers, pair: DsmPairPaths
) -> None:
    """Busy: the stage runs again within 15 s. Idle (the replacement, once the job is
    done): replaced again, and a job queued right after the kill runs."""
    client, auth = api_client(settings)
    supervisor = workers.start()
    site, surveys = upload_dsm_pair(client, auth, pair.pre, pair.post, "recovery")
    job_id, comparison = queue_linger(client, auth, site, surveys, seconds=2.0)
    folder = settings.storage_dir / "comparisons" / str(comparison)
    deadline = time.monotonic() + 60
    while not list(folder.glob("tmp*")):  # the stage is busy in its temporary folder
        assert time.monotonic() < deadline, "the linger stage never started"
        time.sleep(0.02)
    killed = celery_worker_pid(supervisor)
    os.kill(killed, signal.SIGKILL)
    killed_at = time.monotonic()

    def rerun(job: dict) -> bool:
        return job["stages"][-1]["attempts"] >= 2 or job["state"] == "failed"

    job = wait_for_job(client, auth, site, job_id, rerun, timeout_s=60)
    recovered_s = time.monotonic() - killed_at
    job = wait_for_job(client, auth, site, job_id, finished, timeout_s=60)
    finished_s = time.monotonic() - killed_at
    print(f"{settings.resolved_broker_url.split(':')[0]}: run again {recovered_s:.1f} s, "
          f"finished {finished_s:.1f} s after the kill")  # fmt: skip
    assert job["state"] == "succeeded", job
    assert recovered_s <= RECOVERY_TARGET_S
    assert finished_s <= RECOVERY_TARGET_S + 2.0 + 1.0  # + the stage's own 2 s, + storing
    # Killed once, run once more: no attempt ran twice, no other stage ran again.
    attempts = {s["stage"]: s["attempts"] for s in job["stages"]}
    assert attempts == {"align": 1, "coregister": 1, "difference": 1, "linger": 2}
    assert list(folder.glob("tmp*")) == []  # the killed attempt's temporary folder is gone

    replacement = celery_worker_pid(supervisor)  # idle now: its job is done
    assert replacement != killed
    os.kill(replacement, signal.SIGKILL)
    next_job_id, _ = queue_linger(client, auth, site, surveys, seconds=0.0)
    next_job = wait_for_job(client, auth, site, next_job_id, finished, timeout_s=60)
    assert next_job["state"] == "succeeded", next_job
    assert [s["attempts"] for s in next_job["stages"]] == [1, 1, 1, 1]
    assert celery_worker_pid(supervisor) not in (killed, replacement)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def wait_until(condition: Callable[[], object], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def answers(port: int) -> bool:
    try:
        connection = http.client.HTTPConnection("127.0.0.1", port, timeout=1)
        connection.request("GET", "/health")
        return connection.getresponse().status == 200
    except OSError:
        return False


@pytest.fixture
def slidewatch_run(tmp_path: Path) -> Iterator[tuple[subprocess.Popen, int, Path]]:
    """`slidewatch run` on the embedded default, its own process group, a free port; its
    database made at once from the migrated template (its own migration is a no-op)."""
    port = free_port()
    settings = Settings(data_dir=tmp_path / "data")
    settings.data_dir.mkdir(parents=True)
    migrate_new_database(settings.resolved_database_url)
    env = {
        **os.environ,
        "SLIDEWATCH_DATA_DIR": str(settings.data_dir),
        "SLIDEWATCH_API_PORT": str(port),
        "SLIDEWATCH_API_WORKERS": "1",
        "SLIDEWATCH_SEED_DEMO": "false",
        "SLIDEWATCH_SHUTDOWN_GRACE_S": "2",
    }
    log = tmp_path / "run.log"
    with open(log, "wb") as out:
        process = subprocess.Popen(
            [sys.executable, "-m", "backend.cli", "run"],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        wait_until(lambda: len(children_of(process.pid)) >= 3, 60, "run started no children")
        yield process, port, log
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def test_slidewatch_run_restarts_a_dead_child_and_stops_them_all(
    slidewatch_run: tuple[subprocess.Popen, int, Path],
) -> None:
    run, port, log = slidewatch_run
    wait_until(lambda: answers(port), 60, f"the API did not answer:\n{log.read_text()}")
    api = next(pid for pid in children_of(run.pid) if command_line(pid).split()[-1] == "api")
    os.kill(api, signal.SIGKILL)
    wait_until(lambda: not answers(port), 10, "the API still answers")
    wait_until(lambda: answers(port), 60, f"the API was not restarted:\n{log.read_text()}")

    # A request that keeps the API busy: its body never arrives in full.
    busy = socket.create_connection(("127.0.0.1", port))
    busy.sendall(
        b"POST /api/v1/sites HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
        b"Content-Length: 100000\r\n\r\n{"
    )
    processes = descendants_of(run.pid)
    assert len(processes) >= 3, processes  # API, worker, beat (and their own children)
    run.send_signal(signal.SIGTERM)
    run.wait(timeout=2 + 10)  # the grace period, then the kill
    busy.close()
    wait_until(lambda: not any(alive(p) for p in processes), 5, "children outlived run")


def test_children_of_a_killed_slidewatch_run_die_with_it(
    slidewatch_run: tuple[subprocess.Popen, int, Path],
) -> None:
    run, _port, _log = slidewatch_run
    children = children_of(run.pid)
    run.send_signal(signal.SIGKILL)  # the supervisor alone, not its process group
    run.wait()
    wait_until(lambda: not any(alive(p) for p in children), 5, "children outlived run")
