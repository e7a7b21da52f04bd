"""The detection model registry: list models, train new ones in the worker."""

import json
import uuid

from fastapi import APIRouter, HTTPException, status

from backend.api.deps import CeleryDep, CurrentToken, SessionDep, StorageDep
from backend.api.schemas_models import ModelOut, TrainingCreate, TrainingOut
from backend.db.models import ModelVersion
from backend.services import models
from worker.celery_app import QUEUE, TRAIN_MODEL_TASK
from worker.pipeline.cnn.trainer import MODEL_KINDS
from worker.tasks_training import STATUS_FILE, run_folder, write_status

router = APIRouter(prefix="/models", tags=["models"])
DATASETS_FOLDER = "datasets"
API_PREFIX = "/api/v1"


def model_out(row: ModelVersion) -> ModelOut:
    return ModelOut(
        id=row.id,
        name=row.name,
        version=row.version,
        reference=models.reference(row),
        kind=row.kind,
        location=row.location,
        weights_sha256=row.weights_sha256,
        is_default=row.is_default,
        interim=bool(row.card.get("interim", False)),
        created_at=row.created_at,
        card=row.card,
    )


@router.get("", response_model=list[ModelOut], summary="Registered detection models")
def list_models(session: SessionDep, _token: CurrentToken) -> list[ModelOut]:
    rows = models.list_models(session)
    session.commit()  # the shipped model is registered on first use
    return [model_out(row) for row in rows]


@router.post(
    "/training",
    response_model=TrainingOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Train a detection model in the worker and register it",
)
def start_training(
    body: TrainingCreate, storage: StorageDep, celery: CeleryDep, _token: CurrentToken
) -> TrainingOut:
    if body.model_kind not in MODEL_KINDS:
        raise HTTPException(
            status.HTTP_422_UNPROCESSABLE_CONTENT,
            f"unknown model kind {body.model_kind!r}; kinds are {', '.join(MODEL_KINDS)}",
        )
    try:
        manifest = storage.absolute(body.dataset)
    except ValueError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    if not manifest.is_relative_to(storage.absolute(DATASETS_FOLDER)) or not manifest.is_file():
        raise HTTPException(
            status.HTTP_422_UNPROCESSABLE_CONTENT,
            f"no dataset manifest {body.dataset!r} under {DATASETS_FOLDER}/ in storage",
        )
    run = uuid.uuid4().hex[:12]
    write_status(storage, run_folder(body.name, run), state="queued", name=body.name)
    try:
        celery.send_task(
            TRAIN_MODEL_TASK,
            args=[run, body.dataset, body.model_kind, body.name],
            kwargs={"seed": body.seed, "options": body.options, "make_default": body.make_default},
            queue=QUEUE,
        )
    except Exception as exc:  # the broker is down: nothing was queued
        raise HTTPException(
            status.HTTP_503_SERVICE_UNAVAILABLE, f"could not queue the training: {exc}"
        ) from None
    return _training_out(storage, body.name, run)


@router.get("/training/{name}/{run}", response_model=TrainingOut)
def get_training(name: str, run: str, storage: StorageDep, _token: CurrentToken) -> TrainingOut:
    return _training_out(storage, name, run)


def _training_out(storage: StorageDep, name: str, run: str) -> TrainingOut:
    try:
        path = storage.absolute(f"{run_folder(name, run)}/{STATUS_FILE}")
    except ValueError:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "no such training run") from None
    if not path.is_file():
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no training run {name}/{run}")
    state = json.loads(path.read_text())
    return TrainingOut(
        run=run,
        name=name,
        state=state["state"],
        model=state.get("model"),
        error=state.get("error"),
        status_url=f"{API_PREFIX}/models/training/{name}/{run}",
    )
