"""Model training is a job: its state, progress, model and error are served from the
database (no status file), a redelivered "train" resumes from the run folder, and a run
that cannot train fails at once with the reason. Stages run in this process exactly as a
worker runs them."""

from datetime import UTC, datetime, timedelta

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import update

from backend.db.models import Job, StageRun, StageState, TrainingRun
from tests.api_helpers import job_context
from tests.cnn.conftest import write_separable_dataset
from worker.jobs.runner import execute_stage

QUICK = {
    "epochs": 2, "steps_per_epoch": 6, "batch_size": 4, "tile_px": 64,
    "validate_every": 2, "block_px": 120, "scales": [1], "clean_fraction": 0.0,
}  # fmt: skip


def _start(app: FastAPI, client: TestClient, auth: dict, **body) -> dict:
    dataset = app.state.storage.absolute("datasets/pits")
    dataset.mkdir(parents=True, exist_ok=True)
    write_separable_dataset(dataset)
    body = {"dataset": "datasets/pits/dataset.json", "name": "pits", "seed": 1, **body}
    started = client.post("/api/v1/models/training", json=body, headers=auth)
    assert started.status_code == 202, started.text
    return started.json()


def test_training_status_comes_from_its_job_and_the_model_is_registered(
    app: FastAPI, client: TestClient, auth: dict
) -> None:
    started = _start(app, client, auth, options=QUICK)
    assert started["state"] == "queued" and started["kind"] == "slidenet"
    assert started["progress"] == 0.0 and started["model"] is None
    folder = app.state.storage.absolute(f"models/pits/{started['run']}")
    assert not (folder / "status.json").exists()

    assert execute_stage(job_context(), started["job_id"], "train") == "register"
    halfway = client.get(started["status_url"], headers=auth).json()
    assert halfway["state"] == "running" and halfway["progress"] == 0.5
    assert halfway["metrics"]["epochs_run"] == 2

    # The worker died after training, before the stage was recorded: the stage is
    # taken over and the trainer resumes from the run folder's last checkpoint.
    with app.state.sessionmaker() as session:
        session.execute(
            update(StageRun)
            .where(StageRun.job_id == started["job_id"], StageRun.stage == "train")
            .values(state=StageState.running, heartbeat_at=datetime.now(UTC) - timedelta(hours=1))
        )
        session.commit()
    assert execute_stage(job_context(), started["job_id"], "train") == "register"
    assert execute_stage(job_context(), started["job_id"], "register") is None

    run = client.get(started["status_url"], headers=auth).json()
    assert run["state"] == "succeeded" and run["progress"] == 1.0 and run["error"] is None
    assert run["metrics"]["validation"]["patches"] > 0
    with app.state.sessionmaker() as session:
        job = session.get(Job, started["job_id"])
        assert job.site_id is None and job.kind == "training"
        train = job.stages[0]
        assert train.attempts == 2 and train.result["resumed_from_epoch"] == 2
        assert session.get(TrainingRun, job.training_run_id).model == run["model"]
    listed = {m["reference"]: m for m in client.get("/api/v1/models", headers=auth).json()}
    model = listed[run["model"]]
    assert model["name"] == "pits" and model["location"] == "storage"
    assert model["card"]["training"]["seed"] == 1


def test_a_training_that_cannot_run_fails_at_once_with_its_reason(
    app: FastAPI, client: TestClient, auth: dict
) -> None:
    started = _start(app, client, auth, options={"epochs": 1, "no_such_option": 3})
    assert execute_stage(job_context(), started["job_id"], "train") is None
    run = client.get(started["status_url"], headers=auth).json()
    assert run["state"] == "failed" and run["model"] is None
    assert "unknown training options: no_such_option" in run["error"]
    with app.state.sessionmaker() as session:
        [train, register] = session.get(Job, started["job_id"]).stages
        assert (train.state, train.attempts) == (StageState.failed, 1)
        assert register.state == StageState.pending

    missing = client.get("/api/v1/models/training/pits/0123456789ab", headers=auth)
    assert missing.status_code == 404
    refused = client.post(
        "/api/v1/models/training",
        json={"dataset": "../../etc/passwd", "name": "pits"},
        headers=auth,
    )
    assert refused.status_code == 422 and "leaves the storage root" in refused.json()["detail"]
    unknown = client.post(
        "/api/v1/models/training",
        json={"dataset": "datasets/pits/dataset.json", "name": "pits", "model_kind": "unet"},
        headers=auth,
    )
    assert unknown.status_code == 422 and "unknown model kind" in unknown.json()["detail"]
