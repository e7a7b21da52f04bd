"""Request and response bodies of the detection model registry (routes/models.py)."""

from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field


class ModelOut(BaseModel):
    id: int
    name: str
    version: str
    reference: str = Field(description='"name@version": what comparison parameters name.')
    kind: str
    location: str = Field(description="package (shipped) or storage (trained here)")
    weights_sha256: str
    is_default: bool
    interim: bool = Field(description="Trained on stand-in data (see card.data).")
    created_at: datetime
    card: dict[str, Any] = Field(description="The model card: metrics, training data, rule.")


class TrainingCreate(BaseModel):
    dataset: str = Field(
        max_length=1024,
        description="Dataset manifest (slidewatch-detection-dataset/1), a path relative to "
        "the storage root under datasets/.",
    )
    model_kind: str = Field(
        default="slidenet", max_length=32, description="slidenet, patchnet-fixed/-loose"
    )
    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    options: dict[str, Any] = Field(
        default_factory=dict, description="Training options (epochs, steps_per_epoch, ...)."
    )
    make_default: bool = Field(default=False, description="Make it the cnn method's default.")


class TrainingOut(BaseModel):
    run: str
    name: str
    kind: str = Field(description="The model kind trained (slidenet, patchnet-...)")
    state: str = Field(description="queued, running, succeeded or failed: its job's state")
    model: str | None = Field(default=None, description='"name@version" once registered')
    error: str | None = Field(default=None, description="Why it failed, stage first")
    metrics: dict[str, Any] | None = Field(
        default=None, description="Once trained: validation metrics, seconds, epochs run"
    )
    job_id: int | None = Field(default=None, description="The job that runs it")
    progress: float = Field(default=0.0, description="0-1, over both stages")
    status_url: str
