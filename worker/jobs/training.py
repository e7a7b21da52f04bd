"""The training job: train a detection model ("train"), then register it ("register").

The run (a TrainingRun row, backend/services/training.py) names a dataset manifest in
storage; the library trainer (worker/training/trainer.py, the entry point `slidewatch
train` uses too) trains it, seeded, into storage `models/<name>/<run>/`. It writes a
checkpoint after every epoch and resumes from it when run again with the same folder:
a stage taken over after its worker died, or retried after a transient error, goes on
from the last finished epoch.

"register" checks the weights against their model card (no database), then storing it
adds the model_versions row (idempotent: the registry skips a name@version it has) and
keeps its "name@version" on the run. Where the run stands is its job's state.
"""

import hashlib
import json
import logging
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from backend.db import model_registry
from backend.db.models import Job, TrainingRun
from backend.storage_layout import model_run_file, model_run_folder
from worker.jobs.kind import JobKindName
from worker.jobs.products import StorageJob
from worker.pipeline.errors import InputError
from worker.pipeline.progress import ProgressFn

log = logging.getLogger(__name__)
TRAINING_THREADS = 2  # torch threads: the platform's two-core minimum (docs/detection.md)
STAGE_HELP = {
    "train": "Train the model on the dataset, resuming from the last finished epoch",
    "register": "Check the weights against the model card and register the model",
}
# The trainers log one line per finished epoch ("<name> epoch 3/10: loss ..."); the library
# has no progress callback, so the stage's progress is read from those lines.
EPOCH_LINE = re.compile(r"\bepoch (\d+)/(\d+)\b")


def _logging_progress(progress: ProgressFn) -> Callable[[str], None]:
    def log_line(message: str) -> None:
        log.info(message)
        match = EPOCH_LINE.search(message)
        if match and int(match.group(2)) > 0:
            progress(int(match.group(1)) / int(match.group(2)))

    return log_line


def check_weights(card_path: Path) -> dict[str, Any]:
    """The model card, once its weights file is there and matches the card's SHA-256."""
    if not card_path.is_file():
        raise InputError(f"the training left no model card {card_path.name}")
    card = json.loads(card_path.read_text(encoding="utf-8"))
    weights = card_path.parent / card.get("weights_file", "")
    if not card.get("weights_file") or not weights.is_file():
        raise InputError(f"the training left no weights file {weights.name}")
    if hashlib.sha256(weights.read_bytes()).hexdigest() != card.get("weights_sha256"):
        raise InputError(f"the weights {weights.name} do not match their model card")
    return card


class TrainingJob(StorageJob):
    name = JobKindName.training
    stages: tuple[str, ...] = ("train", "register")

    def stage_help(self, stage: str) -> str:
        return STAGE_HELP.get(stage, "")

    def _training(self, session: Session, job: Job) -> TrainingRun:
        return self.owner(session, TrainingRun, job.training_run_id, job.id)

    def load_inputs(self, session: Session, job: Job) -> dict[str, Any]:
        training = self._training(session, job)
        folder = model_run_folder(training.name, training.run)
        trained = next((r.result for r in job.stages if r.stage == "train"), None) or {}
        return {
            "dataset": str(self.storage.absolute(training.dataset)),
            "out_dir": str(self.storage.absolute(folder)),
            "model_kind": training.model_kind,
            "name": training.name,
            "seed": training.seed,
            "options": dict(training.options or {}),
            "card_file": trained.get("card_file"),
        }

    def run_stage(self, stage: str, inputs: dict[str, Any], progress: ProgressFn) -> dict[str, Any]:
        out_dir = Path(inputs["out_dir"])
        if stage == "register":
            card = check_weights(out_dir / inputs["card_file"])
            return {
                "card_file": inputs["card_file"],
                "weights_file": card["weights_file"],
                "model": f"{card['name']}@{card['version']}",
            }
        from worker.training.trainer import train_model  # imports torch: only when training

        out_dir.mkdir(parents=True, exist_ok=True)
        try:
            result = train_model(
                Path(inputs["dataset"]),
                out_dir,
                inputs["model_kind"],
                inputs["name"],
                seed=inputs["seed"],
                threads=TRAINING_THREADS,
                overrides=inputs["options"],
                log=_logging_progress(progress),
            )
        except ValueError as exc:
            # A manifest or option the trainer cannot use: running again will not help.
            raise InputError(str(exc)) from exc
        return {
            "card_file": result.card_path.name,
            "validation": result.card.metrics.get("validation"),
            "seconds": round(result.seconds, 1),
            "epochs_run": len(result.history),
            "resumed_from_epoch": result.resumed_from_epoch,
        }

    def store_stage_result(
        self, session: Session, job: Job, stage: str, result: dict[str, Any]
    ) -> None:
        training = self._training(session, job)
        if stage == "train":
            training.metrics = {
                key: result.get(key) for key in ("validation", "seconds", "epochs_run")
            }
            return
        row = model_registry.register_model(
            session,
            self.storage.absolute(model_run_file(training.name, training.run, result["card_file"])),
            model_registry.STORAGE,
            model_run_file(training.name, training.run, result["weights_file"]),
            training.make_default,
        )
        training.model = model_registry.reference(row)

    def on_success(self, session: Session, job: Job) -> None:
        """Nothing to do: the run's state is its job's, and "register" kept the model."""

    def on_failure(self, session: Session, job: Job, reason: str) -> None:
        """Nothing to do: the job keeps the state and the reason the API shows."""

    def on_retry(self, session: Session, job: Job) -> None:
        """Nothing to reset: a retried "train" resumes from the run folder's checkpoint."""
