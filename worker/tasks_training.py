"""Celery task: train a detection model and register it (thin adapter over the library).

The API (POST /api/v1/models/training) names a dataset manifest in storage and a run id;
the model is trained, seeded, into storage `models/<name>/<run>/` by the library
(worker/pipeline/cnn/trainer.py) and registered as a model_versions row. The run's
`status.json` says where it stands (running, succeeded with the model's "name@version",
failed with the reason): GET /api/v1/models/training/{run}. A redelivered message (the
worker died) resumes from the last finished epoch's checkpoint in the same folder.
"""

import json
import logging
import traceback
from typing import Any

from backend.config import get_settings
from backend.db.session import session_scope
from backend.services import models
from backend.storage import LocalStorage
from worker.celery_app import TRAIN_MODEL_TASK, app
from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.errors import InputError

log = logging.getLogger(__name__)
STATUS_FILE = "status.json"
TRAINING_THREADS = 2  # torch threads: the platform's two-core minimum (docs/detection.md)


def run_folder(name: str, run: str) -> str:
    """Storage folder (relative) of one training run."""
    return f"{models.MODELS_FOLDER}/{name}/{run}"


def write_status(storage: LocalStorage, folder: str, **status: Any) -> None:
    path = storage.absolute(f"{folder}/{STATUS_FILE}")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(status))


@app.task(name=TRAIN_MODEL_TASK)
def train_model_task(
    run: str,
    dataset: str,
    model_kind: str,
    name: str,
    seed: int = 0,
    options: dict[str, Any] | None = None,
    make_default: bool = False,
) -> None:
    from worker.pipeline.cnn.trainer import train_model

    storage = LocalStorage(get_settings().storage_dir)
    folder = run_folder(name, run)
    storage.absolute(folder).mkdir(parents=True, exist_ok=True)
    write_status(storage, folder, state="running", name=name, kind=model_kind)
    try:
        result = train_model(
            storage.absolute(dataset),
            storage.absolute(folder),
            model_kind,
            name,
            seed=seed,
            threads=TRAINING_THREADS,
            overrides=options,
            log=log.info,
        )
        with session_scope() as session:
            row = models.register_model(
                session, result.card_path, models.STORAGE, f"{folder}/{name}.pt", make_default
            )
            reference = models.reference(row)
    except (InputError, ValueError) as exc:
        write_status(storage, folder, state="failed", name=name, kind=model_kind, error=str(exc))
        return
    except Exception as exc:
        log.exception("training run %s failed", run)
        write_status(
            storage, folder, state="failed", name=name, kind=model_kind,
            error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(limit=5),
        )  # fmt: skip
        return
    write_status(
        storage, folder, state="succeeded", name=name, kind=model_kind, model=reference,
        validation=result.card.metrics.get("validation"), seconds=round(result.seconds, 1),
    )  # fmt: skip
