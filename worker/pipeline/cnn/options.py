"""Light-weight pieces of the detection library that do not import torch: the cnn
stage's options and where the shipped weights live (the API imports these)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

PACKAGE_WEIGHTS = Path(__file__).resolve().parent / "weights"
DEFAULT_MODEL_NAME = "slidenet-default"


@dataclass
class CnnOptions:
    """Options of the comparison's `detect` stage (method cnn)."""

    model: str | None = None  # None / "default": the shipped model; else a card path
    tile_px: int = 1024
    pixel_threshold: float | None = None  # None: the model card's decision rule
    scales: list[int] | None = None  # test-time pyramid; None: the model card's
    min_score: float | None = None  # least mean probability of a landslide; None: card's
    min_area_px: int = 103  # 10 % of a 32-pixel cell
    min_area_m2: float | None = None  # overrides min_area_px when set
    num_threads: int = 2


def default_model_path() -> Path | None:
    """The shipped default model's card, or None when no weights ship."""
    card = PACKAGE_WEIGHTS / f"{DEFAULT_MODEL_NAME}.json"
    weights = PACKAGE_WEIGHTS / f"{DEFAULT_MODEL_NAME}.pt"
    return card if card.exists() and weights.exists() else None
