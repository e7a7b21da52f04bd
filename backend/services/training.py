"""Training detection models in the worker, as jobs.

`start_training` records a TrainingRun and its job (kind "training",
worker/jobs/training.py: "train", then "register"), run by the same stage runner as
comparisons: retries with backoff, heartbeats, stall recovery, progress. Where a run
stands is its job's state, progress and error, read from the database; once registered,
the model's "name@version" is kept on the run. The weights, the model card and the
checkpoints a redelivered "train" resumes from are in storage `models/<name>/<run>/`.
A training job belongs to no site (models are shared by every site).
"""

import uuid
from typing import Any

from celery import Celery
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import TrainingRun
from backend.storage import LocalStorage
from backend.storage_layout import DATASETS_FOLDER
from worker.jobs.control import TRAINABLE_MODEL_KINDS, JobKindName, new_job, start_job


class TrainingRejected(ValueError):
    """The training request cannot be run; the message says why."""


def start_training(
    celery: Celery,
    session: Session,
    storage: LocalStorage,
    *,
    dataset: str,
    model_kind: str,
    name: str,
    seed: int = 0,
    options: dict[str, Any] | None = None,
    make_default: bool = False,
) -> TrainingRun:
    """Record a training run and queue its job; QueueUnavailable when nothing was queued
    (the job is then failed), TrainingRejected for a request that cannot run."""
    if model_kind not in TRAINABLE_MODEL_KINDS:
        raise TrainingRejected(
            f"unknown model kind {model_kind!r}; kinds are {', '.join(TRAINABLE_MODEL_KINDS)}"
        )
    try:
        manifest = storage.absolute(dataset)
    except ValueError as exc:
        raise TrainingRejected(str(exc)) from None
    # Only manifests under datasets/ in storage: the worker opens what the API user names.
    if not manifest.is_relative_to(storage.absolute(DATASETS_FOLDER)) or not manifest.is_file():
        raise TrainingRejected(
            f"no dataset manifest {dataset!r} under {DATASETS_FOLDER}/ in storage"
        )
    training = TrainingRun(
        run=uuid.uuid4().hex[:12],
        name=name,
        model_kind=model_kind,
        dataset=dataset,
        seed=seed,
        options=dict(options or {}),
        make_default=make_default,
    )
    session.add(training)
    session.flush()
    job = new_job(None, JobKindName.training, training_run_id=training.id)
    session.add(job)
    session.commit()
    start_job(celery, session, job)
    return training


def find_training(session: Session, name: str, run: str) -> TrainingRun | None:
    return session.scalar(
        select(TrainingRun).where(TrainingRun.run == run, TrainingRun.name == name)
    )
