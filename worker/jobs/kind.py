"""What a kind of job provides to the stage runner."""

from enum import StrEnum
from typing import Any, Protocol

from sqlalchemy.orm import Session

from backend.db.models import Job
from worker.pipeline.progress import ProgressFn


class JobKindName(StrEnum):
    comparison = "comparison"
    reconstruction = "reconstruction"
    report = "report"
    training = "training"


class JobKind(Protocol):
    name: str
    stages: tuple[str, ...]

    def stage_help(self, stage: str) -> str:
        """One line for people on what the stage does (the page shows it by the stage)."""

    def load_inputs(self, session: Session, job: Job) -> dict[str, Any]:
        """Everything the stages need, as plain JSON-friendly data read from the database."""

    def run_stage(self, stage: str, inputs: dict[str, Any], progress: ProgressFn) -> dict[str, Any]:
        """Run one stage of the pipeline library (no database access); return its result."""

    def store_stage_result(
        self, session: Session, job: Job, stage: str, result: dict[str, Any]
    ) -> None:
        """Persist what the stage produced (products, detections). Must be idempotent."""

    def on_success(self, session: Session, job: Job) -> None: ...

    def on_failure(self, session: Session, job: Job, reason: str) -> None: ...

    def on_retry(self, session: Session, job: Job) -> None:
        """A failed job runs again: put what it owns back to its queued state."""
