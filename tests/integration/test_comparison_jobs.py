"""A comparison runs to the end in a real Celery worker process, and survives SIGKILL.

The run undisturbed on Redis + PostgreSQL (the scaled-out deployment); the SIGKILL in the
middle of a real stage (co-registration of a large pair) on the embedded default (SQLite
database, SQLite broker), the way `make run` starts it, which then runs to the end. A kill
in the middle of a stage on both brokers, and its 15 s bound, is
tests/integration/test_worker_recovery.py's.
"""

from collections.abc import Callable
from pathlib import Path

import pytest

from backend.config import Settings
from tests.integration.conftest import (
    SlidewatchProcess,
    api_client,
    upload_dsm_pair,
    wait_for_job,
)
from worker.simulator.dsm_pair import DsmPair, DsmPairPaths, make_dsm_pair, write_dsm_pair

pytestmark = pytest.mark.integration

SHIFT_M = (1.6, -0.9, 0.3)


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[DsmPair, DsmPairPaths]:
    """A pair for jobs that run to the end: co-registered within 0.001 px, the slide's
    area within 0.2 % (the checks allow 0.1 px and 5 %)."""
    dsm_pair = make_dsm_pair(shape=(600, 600), pixel_size_m=0.5, shift_m=SHIFT_M, seed=11)
    return dsm_pair, write_dsm_pair(dsm_pair, tmp_path_factory.mktemp("pair"))


@pytest.fixture(scope="module")
def large_pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[DsmPair, DsmPairPaths]:
    # Large enough that co-registration runs for a few seconds: time to kill the worker.
    dsm_pair = make_dsm_pair(shape=(1200, 1200), pixel_size_m=0.5, shift_m=SHIFT_M, seed=11)
    return dsm_pair, write_dsm_pair(dsm_pair, tmp_path_factory.mktemp("large-pair"))


def submit_comparison(client, auth, paths: DsmPairPaths) -> tuple[int, int]:
    site, ids = upload_dsm_pair(client, auth, paths.pre, paths.post)
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": ids[0], "post_survey_id": ids[1], "method": "threshold"},
        headers=auth,
    )
    assert created.status_code == 202, created.text
    return site, created.json()["job"]["id"]


def check_result(client, auth, site: int, job: dict, pair: DsmPair) -> list[dict]:
    assert job["state"] == "succeeded", job
    coregister = next(s for s in job["stages"] if s["stage"] == "coregister")["result"]
    pixel = pair.pixel_size_m  # the correction applied to post undoes its displacement
    assert abs(coregister["shift_east_m"] + SHIFT_M[0]) < 0.1 * pixel
    assert abs(coregister["shift_north_m"] + SHIFT_M[1]) < 0.1 * pixel
    features = client.get(
        f"/api/v1/sites/{site}/comparisons/{job['comparison_id']}/detections", headers=auth
    ).json()["features"]
    assert len(features) == 1
    area = features[0]["properties"]["area_m2"]
    assert abs(area - pair.truth.area_m2) / pair.truth.area_m2 < 0.05
    return features


def test_comparison_runs_to_the_end_in_a_worker(
    redis_postgres_settings: Settings,
    start_worker: Callable[..., SlidewatchProcess], pair: tuple[DsmPair, DsmPairPaths],
) -> None:  # fmt: skip
    settings = redis_postgres_settings
    client, auth = api_client(settings)
    start_worker(settings)
    site, job_id = submit_comparison(client, auth, pair[1])
    job = wait_for_job(client, auth, site, job_id, lambda j: j["state"] in ("succeeded", "failed"))
    check_result(client, auth, site, job, pair[0])
    assert [s["attempts"] for s in job["stages"]] == [1, 1, 1, 1]


def test_worker_killed_mid_stage_loses_no_job(
    embedded_settings: Settings,
    start_worker: Callable[..., SlidewatchProcess], large_pair: tuple[DsmPair, DsmPairPaths],
) -> None:  # fmt: skip
    pair, settings = large_pair, embedded_settings
    client, auth = api_client(settings)
    worker = start_worker(settings)
    site, job_id = submit_comparison(client, auth, pair[1])

    def coregistering_or_past_it(job: dict) -> bool:
        return job["stages"][1]["state"] != "pending" or job["state"] == "failed"

    job = wait_for_job(client, auth, site, job_id, coregistering_or_past_it)
    assert job["stages"][1]["state"] == "running", "co-registration finished before the kill"
    worker.kill()
    job = client.get(f"/api/v1/sites/{site}/jobs/{job_id}", headers=auth).json()
    assert job["stages"][1]["state"] == "running"  # nobody finished it

    start_worker(settings)
    job = wait_for_job(client, auth, site, job_id, lambda j: j["state"] in ("succeeded", "failed"))
    check_result(client, auth, site, job, pair[0])
    attempts = {s["stage"]: s["attempts"] for s in job["stages"]}
    assert attempts == {"align": 1, "coregister": 2, "difference": 1, "vectorize": 1}


def test_transient_failure_is_retried_with_backoff(
    tmp_path: Path, start_worker: Callable[..., SlidewatchProcess],
    pair: tuple[DsmPair, DsmPairPaths],
) -> None:  # fmt: skip
    settings = Settings(data_dir=tmp_path / "data")  # embedded: the fastest to set up
    client, auth = api_client(settings)
    # Something else holds the path where the job writes its files (a file, not a
    # folder): writing fails with an OSError until it goes away.
    blocker = settings.storage_dir / "comparisons" / "1"
    blocker.parent.mkdir(parents=True)
    blocker.write_text("in the way")
    start_worker(settings)
    site, job_id = submit_comparison(client, auth, pair[1])

    def retrying(job: dict) -> bool:
        return "retrying in" in (job["stages"][0]["error"] or "") or job["state"] == "failed"

    # The first retry's 2 s may pass between two looks on a loaded machine: the stage's
    # log, not its latest error, shows every backoff.
    job = wait_for_job(client, auth, site, job_id, retrying)
    align = job["stages"][0]
    assert job["state"] == "running" and align["state"] in ("pending", "running"), align
    assert "attempt 1 failed, retrying in 2 s" in "\n".join(align["log"]), align
    blocker.unlink()

    job = wait_for_job(client, auth, site, job_id, lambda j: j["state"] in ("succeeded", "failed"))
    check_result(client, auth, site, job, pair[0])
    align = job["stages"][0]
    delays = [
        int(line.split("retrying in ")[1].split(" s")[0])
        for line in align["log"]
        if "retrying in" in line
    ]
    assert delays == [2 * 2**i for i in range(len(delays))], align["log"]  # 2, 4, 8 ... s
    assert align["attempts"] == len(delays) + 1
    assert align["error"] is None
