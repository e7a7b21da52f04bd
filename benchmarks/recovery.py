"""How long a killed worker's stage takes to run again: kill trials on both brokers.

Starts `slidewatch worker` (one worker process, supervised) and beat with the deployment's
default recovery settings, on the embedded default (SQLite database and broker) and on
Redis + PostgreSQL, and SIGKILLs the worker process in turn:

- busy: while the stage `linger` of the test method tests/plugins/slow_method.py is running
  (busy for 3 s in a temporary folder); recovery is the time from the kill until that
  stage is claimed again (its second attempt starts), and the job must then succeed with
  that stage run exactly twice and no temporary folder left;
- idle: while no job runs, then a job is queued at once; recovery is the time from the
  kill until the job's first stage starts.

Prints one line per trial and the median and worst per broker, and writes JSON.

    scripts/with-test-services.sh .venv/bin/python benchmarks/recovery.py --trials 10 \\
        --json benchmarks/results/recovery.json

Redis + PostgreSQL are those of SLIDEWATCH_TEST_REDIS_URL and SLIDEWATCH_TEST_DATABASE_URL
(as the tests use them; a database `slidewatch_recovery_bench` and Redis database 13 are
made empty for the run); `--brokers embedded` runs without them.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fastapi.testclient import TestClient  # noqa: E402
from sqlalchemy import create_engine, make_url, select  # noqa: E402

from backend.api.app import create_app  # noqa: E402
from backend.config import Settings  # noqa: E402
from backend.db.migrate import upgrade  # noqa: E402
from backend.db.models import Job, StageRun, StageState  # noqa: E402
from backend.db.tokens import create_token  # noqa: E402
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair  # noqa: E402

SLOW_MODULE = "tests.plugins.slow_method"
BUSY_STAGE_S = 3.0
TARGET_S = 15.0
BENCH_DATABASE = "slidewatch_recovery_bench"
BENCH_REDIS_DB = 13


def children_of(pid: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


def worker_process(supervisor: subprocess.Popen) -> int:
    """The Celery worker process under `slidewatch worker`, once it is there."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        for pid in children_of(supervisor.pid):
            if b" worker " in Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" "):
                return pid
        time.sleep(0.05)
    raise RuntimeError("no worker process")


def postgres_settings(data_dir: Path) -> Settings:
    server = os.environ.get(
        "SLIDEWATCH_TEST_DATABASE_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres"
    )
    admin = create_engine(server, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.exec_driver_sql(f'DROP DATABASE IF EXISTS "{BENCH_DATABASE}" WITH (FORCE)')
        connection.exec_driver_sql(f'CREATE DATABASE "{BENCH_DATABASE}"')
    admin.dispose()
    redis_url = os.environ.get("SLIDEWATCH_TEST_REDIS_URL", "redis://127.0.0.1:6379/0")
    redis_url = redis_url.rsplit("/", 1)[0] + f"/{BENCH_REDIS_DB}"
    import redis

    redis.Redis.from_url(redis_url).flushdb()
    database = make_url(server).set(database=BENCH_DATABASE).render_as_string(hide_password=False)
    return Settings(data_dir=data_dir, database_url=database, broker_url=redis_url)


class Deployment:
    """The API in this process (a test client), a supervised worker and beat in others."""

    def __init__(self, settings: Settings, logs: Path) -> None:
        self.settings = settings.model_copy(update={"detection_method_modules": [SLOW_MODULE]})
        self.settings.data_dir.mkdir(parents=True, exist_ok=True)
        upgrade(self.settings.resolved_database_url)
        app = create_app(self.settings)
        self.sessions = app.state.sessionmaker
        with self.sessions() as session:
            token = create_token(session, "recovery benchmark")
            session.commit()
        self.client = TestClient(app)
        self.auth = {"Authorization": f"Bearer {token}"}
        env = {
            **os.environ,
            "SLIDEWATCH_DATA_DIR": str(self.settings.data_dir),
            "SLIDEWATCH_DATABASE_URL": self.settings.resolved_database_url,
            "SLIDEWATCH_BROKER_URL": self.settings.resolved_broker_url,
            "SLIDEWATCH_DETECTION_METHOD_MODULES": json.dumps([SLOW_MODULE]),
            "PYTHONPATH": str(ROOT),
        }
        self.processes = [
            subprocess.Popen(
                [sys.executable, "-m", "backend.cli", *args],
                env=env,
                stdout=open(logs / f"{args[0]}.log", "ab"),  # noqa: SIM115 (lives with it)
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
            for args in (["worker"], ["beat"])
        ]
        self.supervisor = self.processes[0]
        self.submitted = 0
        pair = make_dsm_pair(shape=(200, 200), pixel_size_m=0.5, shift_m=(0.4, 0.2, 0.1), seed=5)
        paths = write_dsm_pair(pair, self.settings.data_dir / "pair")
        site = self.client.post("/api/v1/sites", json={"name": "bench"}, headers=self.auth)
        self.site = site.json()["id"]
        self.surveys = []
        dates = ("2026-06-01T10:00:00Z", "2026-07-01T10:00:00Z")
        for path, when in zip((paths.pre, paths.post), dates, strict=True):
            created = self.client.post(
                f"/api/v1/sites/{self.site}/surveys",
                params={"captured_at": when},
                content=path.read_bytes(),
                headers={**self.auth, "Content-Type": "image/tiff"},
            )
            self.surveys.append(created.json()["id"])

    def submit(self, seconds: float) -> tuple[int, int]:
        # A comparison asked for again with the same parameters is the existing one: each
        # trial's lasts a millisecond longer.
        self.submitted += 1
        seconds += self.submitted / 1000
        created = self.client.post(
            f"/api/v1/sites/{self.site}/comparisons",
            json={
                "pre_survey_id": self.surveys[0],
                "post_survey_id": self.surveys[1],
                "method": "linger",
                "parameters": {"linger": {"seconds": seconds}},
            },
            headers=self.auth,
        )
        assert created.status_code == 202, created.text
        job = created.json()["job"]
        return job["id"], job["comparison_id"]

    def stages(self, job_id: int) -> list[StageRun]:
        with self.sessions() as session:
            return list(
                session.scalars(
                    select(StageRun).where(StageRun.job_id == job_id).order_by(StageRun.position)
                )
            )

    def job_state(self, job_id: int) -> str:
        with self.sessions() as session:
            return session.get(Job, job_id).state.value

    def wait(self, job_id: int, until, timeout_s: float = 120) -> None:
        deadline = time.monotonic() + timeout_s
        while not until(self.stages(job_id)):
            if time.monotonic() > deadline:
                raise RuntimeError(f"job {job_id} did not get there: {self.stages(job_id)}")
            time.sleep(0.05)

    def wait_finished(self, job_id: int) -> str:
        deadline = time.monotonic() + 120
        while (state := self.job_state(job_id)) not in ("succeeded", "failed"):
            if time.monotonic() > deadline:
                raise RuntimeError(f"job {job_id} did not finish")
            time.sleep(0.1)
        return state

    def busy_trial(self) -> dict:
        job_id, comparison = self.submit(BUSY_STAGE_S)
        folder = self.settings.storage_dir / "comparisons" / str(comparison)
        deadline = time.monotonic() + 120
        while not list(folder.glob("tmp*")):
            if time.monotonic() > deadline:
                raise RuntimeError("the linger stage did not start")
            time.sleep(0.01)
        os.kill(worker_process(self.supervisor), signal.SIGKILL)
        killed = time.monotonic()
        self.wait(job_id, lambda runs: runs[-1].attempts >= 2)
        recovered = time.monotonic() - killed
        state = self.wait_finished(job_id)
        runs = self.stages(job_id)
        return {
            "kind": "busy",
            "recovery_s": round(recovered, 2),
            "finished_s": round(time.monotonic() - killed, 2),
            "job": state,
            "attempts": [r.attempts for r in runs],
            "temporaries_left": len(list(folder.glob("tmp*"))),
        }

    def idle_trial(self) -> dict:
        time.sleep(1.0)  # idle: no stage running, the worker waits for messages
        os.kill(worker_process(self.supervisor), signal.SIGKILL)
        killed = time.monotonic()
        job_id, _ = self.submit(0.0)
        self.wait(job_id, lambda runs: runs[0].state != StageState.pending)
        recovered = time.monotonic() - killed
        state = self.wait_finished(job_id)
        return {
            "kind": "idle",
            "recovery_s": round(recovered, 2),
            "finished_s": round(time.monotonic() - killed, 2),
            "job": state,
            "attempts": [r.attempts for r in self.stages(job_id)],
            "temporaries_left": 0,
        }

    def stop(self) -> None:
        for process in self.processes:
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=10, help="kill trials per broker")
    parser.add_argument(
        "--brokers", default="embedded,redis", help="comma-separated: embedded, redis"
    )
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    results: dict[str, dict] = {}
    for broker in args.brokers.split(","):
        with tempfile.TemporaryDirectory(prefix="slidewatch-recovery-") as tmp:
            data = Path(tmp) / "data"
            settings = Settings(data_dir=data) if broker == "embedded" else postgres_settings(data)
            deployment = Deployment(settings, Path(tmp))
            trials = []
            try:
                worker_process(deployment.supervisor)
                for i in range(args.trials):
                    trial = deployment.busy_trial() if i % 2 == 0 else deployment.idle_trial()
                    trials.append(trial)
                    print(
                        f"{broker:8s} trial {i + 1:2d} {trial['kind']:4s}: run again "
                        f"{trial['recovery_s']:5.1f} s after the kill, job {trial['job']} after "
                        f"{trial['finished_s']:5.1f} s, attempts {trial['attempts']}, "
                        f"temporaries left {trial['temporaries_left']}",
                        flush=True,
                    )
            finally:
                deployment.stop()
        times = [t["recovery_s"] for t in trials]
        results[broker] = {
            "trials": trials,
            "median_s": round(statistics.median(times), 2),
            "worst_s": max(times),
            "within_target": sum(t <= TARGET_S for t in times),
        }
        print(
            f"{broker}: recovery median {results[broker]['median_s']:.1f} s, worst "
            f"{results[broker]['worst_s']:.1f} s, {results[broker]['within_target']} of "
            f"{len(times)} within {TARGET_S:.0f} s",
            flush=True,
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
