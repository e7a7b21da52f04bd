"""The cnn method and model training in a real Celery worker process (embedded default:
SQLite database and broker, the way `make run` starts it)."""

import shutil
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from backend.config import Settings
from tests.api_helpers import request_comparison, upload_dsm
from tests.cnn.conftest import mound_pair, write_separable_dataset
from tests.integration.conftest import SlidewatchProcess, api_client, wait_for_job

pytestmark = pytest.mark.integration

QUICK = {"coregister": {"subsample": 50_000}}  # the same result on these small pairs


def test_cnn_finds_the_planted_slide_in_a_worker(
    tmp_path: Path, start_worker: Callable[..., SlidewatchProcess]
) -> None:
    """The cnn comparison as a job in a worker process; that it finds nothing on the
    no-change pair of the same field is tests/cnn/test_cnn_weights.py's (in process)."""
    settings = Settings(data_dir=tmp_path / "data")
    client, auth = api_client(settings)
    start_worker(settings)
    site = client.post("/api/v1/sites", json={"name": "mounds"}, headers=auth).json()["id"]
    pre_path, post_path = mound_pair(True, 3).write(tmp_path / "slide")
    pre = upload_dsm(client, auth, site, pre_path, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site, post_path, "2026-07-01T10:00:00Z")
    created = request_comparison(client, auth, site, pre["id"], post["id"], "cnn", parameters=QUICK)
    assert created.status_code == 202, created.text
    assert created.json()["comparison"]["method"] == "cnn"
    job = wait_for_job(
        client,
        auth,
        site,
        created.json()["job"]["id"],
        lambda j: j["state"] in ("succeeded", "failed"),
    )
    assert job["state"] == "succeeded", job
    assert [s["stage"] for s in job["stages"]][-1] == "detect"
    found = client.get(
        f"/api/v1/sites/{site}/comparisons/{job['comparison_id']}/detections", headers=auth
    ).json()["features"]
    assert len(found) == 1
    props = found[0]["properties"]
    assert props["method"] == "cnn" and props["model_version"].startswith("slidenet-default@")
    assert 10 < props["area_m2"] < 40 and props["score"] >= 0.7


def test_a_model_trained_in_the_worker_is_registered(
    tmp_path: Path, start_worker: Callable[..., SlidewatchProcess]
) -> None:
    settings = Settings(data_dir=tmp_path / "data")
    client, auth = api_client(settings)
    dataset = settings.storage_dir / "datasets" / "pits"
    dataset.mkdir(parents=True)
    write_separable_dataset(dataset)
    start_worker(settings, beat=False)
    options = {
        "epochs": 2, "steps_per_epoch": 6, "batch_size": 4, "tile_px": 64,
        "validate_every": 2, "block_px": 120, "scales": [1], "clean_fraction": 0.0,
    }  # fmt: skip
    body = {"dataset": "datasets/pits/dataset.json", "name": "pits", "seed": 1, "options": options}
    started = client.post("/api/v1/models/training", json=body, headers=auth)
    assert started.status_code == 202, started.text
    status_url = started.json()["status_url"]
    deadline = time.monotonic() + 180
    while (run := client.get(status_url, headers=auth).json())["state"] in ("queued", "running"):
        assert time.monotonic() < deadline, run
        time.sleep(0.5)
    assert run["state"] == "succeeded", run
    listed = {m["reference"]: m for m in client.get("/api/v1/models", headers=auth).json()}
    model = listed[run["model"]]
    assert model["name"] == "pits" and model["location"] == "storage"
    assert not model["is_default"]  # the shipped model stays the default
    assert model["card"]["training"]["seed"] == 1 and model["card"]["training"]["epochs_run"] == 2
    assert model["card"]["training"]["exclude"]["region"] == "top"  # test region held out
    assert model["card"]["metrics"]["validation"]["patches"] > 0
    refused = client.post(
        "/api/v1/models/training", json={**body, "dataset": "../../etc/passwd"}, headers=auth
    )
    assert refused.status_code == 422
    shutil.rmtree(dataset)
