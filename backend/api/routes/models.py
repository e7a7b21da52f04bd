"""The detection model registry: list models, train new ones in the worker.

A training run is a job (kind "training": stages "train", "register") like every piece
of background work; its state, progress and error are the job's, read from the database.
"""

from fastapi import APIRouter, HTTPException, status

from backend.api.access import PlatformAdmin, SignedIn
from backend.api.deps import CeleryDep, SessionDep, StorageDep
from backend.api.schemas_models import ModelOut, TrainingCreate, TrainingOut
from backend.db import model_registry
from backend.db.models import JobState, ModelVersion, TrainingRun
from backend.services import training as trainings
from backend.urls import api_url
from worker.jobs.control import QueueUnavailable, job_progress

router = APIRouter(prefix="/models", tags=["models"])


def model_out(row: ModelVersion) -> ModelOut:
    return ModelOut(
        id=row.id,
        name=row.name,
        version=row.version,
        reference=model_registry.reference(row),
        kind=row.kind,
        location=row.location,
        weights_sha256=row.weights_sha256,
        is_default=row.is_default,
        interim=bool(row.card.get("interim", False)),
        created_at=row.created_at,
        card=row.card,
    )


@router.get("", response_model=list[ModelOut], summary="Registered detection models")
def list_models(session: SessionDep, _token: SignedIn) -> list[ModelOut]:
    rows = model_registry.list_models(session)
    session.commit()  # the shipped model is registered on first use
    return [model_out(row) for row in rows]


@router.post(
    "/training",
    response_model=TrainingOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Train a detection model in the worker and register it",
)
def start_training(
    body: TrainingCreate,
    session: SessionDep,
    storage: StorageDep,
    celery: CeleryDep,
    _token: PlatformAdmin,
) -> TrainingOut:
    try:
        training = trainings.start_training(
            celery,
            session,
            storage,
            dataset=body.dataset,
            model_kind=body.model_kind,
            name=body.name,
            seed=body.seed,
            options=body.options,
            make_default=body.make_default,
        )
    except trainings.TrainingRejected as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    except QueueUnavailable as exc:  # the broker is down: nothing was queued
        raise HTTPException(
            status.HTTP_503_SERVICE_UNAVAILABLE, f"could not queue the training: {exc}"
        ) from None
    return training_out(training)


@router.get(
    "/training/{name}/{run}",
    response_model=TrainingOut,
    summary="Where a training run stands (its job's state) and the model it registered",
)
def get_training(name: str, run: str, session: SessionDep, _token: SignedIn) -> TrainingOut:
    training = trainings.find_training(session, name, run)
    if training is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no training run {name}/{run}")
    return training_out(training)


def training_out(training: TrainingRun) -> TrainingOut:
    job = training.job
    state = job.state if job is not None else JobState.failed
    return TrainingOut(
        run=training.run,
        name=training.name,
        kind=training.model_kind,
        state=state,
        model=training.model if state == JobState.succeeded else None,
        error=job.error if job is not None else "the training run has no job",
        metrics=training.metrics,
        job_id=job.id if job is not None else None,
        progress=job_progress(job) if job is not None else 0.0,
        status_url=api_url("models", "training", training.name, training.run),
    )
