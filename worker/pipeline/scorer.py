"""The candidate scorer of the `scored` method: a landslide probability per region.

A logistic model over the traits of a change region (change_regions.Region.traits:
how far beyond its LoD, how large against the errors' correlation, how coherent, whether
it is a tall object that appeared or vanished, ...), trained on some pair generators
(worker/detection_bench/scorer_training.py) and calibrated (Platt scaling) on others,
so that its score is a probability: of the candidates scored 0.8, about 80 % are
landslides on ground the model never saw. The operating threshold was chosen for recall
first on the calibration generators and is in the card.

The weights ship as one JSON file with the model card (`scorer_weights/`): traits in
order, their standardisation, coefficients, calibration, threshold, the generators of
training and calibration, and the benchmark figures.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

WEIGHTS_DIR = Path(__file__).parent / "scorer_weights"
DEFAULT_SCORER = WEIGHTS_DIR / "scorer-default.json"


@dataclass(frozen=True)
class Scorer:
    name: str
    version: str
    traits: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    coefficients: np.ndarray
    intercept: float
    calibration: tuple[float, float]  # Platt: p = sigmoid(a * logit + b)
    threshold: float
    card: dict[str, Any]

    @property
    def reference(self) -> str:
        return f"{self.name}@{self.version}"

    def logit(self, traits: list[dict[str, float]]) -> np.ndarray:
        x = np.array([[t[name] for name in self.traits] for t in traits], dtype=float)
        x = (x.reshape(-1, len(self.traits)) - self.mean) / self.scale
        return x @ self.coefficients + self.intercept

    def probability(self, traits: list[dict[str, float]]) -> np.ndarray:
        if not traits:
            return np.zeros(0)
        a, b = self.calibration
        return _sigmoid(a * self.logit(traits) + b)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "version": self.version,
            "traits": list(self.traits),
            "mean": self.mean.tolist(),
            "scale": self.scale.tolist(),
            "coefficients": self.coefficients.tolist(),
            "intercept": self.intercept,
            "calibration": list(self.calibration),
            "threshold": self.threshold,
            "card": self.card,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Scorer:
        return cls(
            name=str(data["name"]),
            version=str(data["version"]),
            traits=tuple(data["traits"]),
            mean=np.asarray(data["mean"], dtype=float),
            scale=np.asarray(data["scale"], dtype=float),
            coefficients=np.asarray(data["coefficients"], dtype=float),
            intercept=float(data["intercept"]),
            calibration=(float(data["calibration"][0]), float(data["calibration"][1])),
            threshold=float(data["threshold"]),
            card=dict(data.get("card") or {}),
        )


def load_scorer(path: Path | None = None) -> Scorer:
    """The scorer at `path`, else the shipped default."""
    path = Path(path) if path is not None else DEFAULT_SCORER
    return Scorer.from_dict(json.loads(path.read_text()))


def shipped_scorer_available() -> bool:
    return DEFAULT_SCORER.exists()


def training_generators() -> tuple[str, ...]:
    """Generators the shipped scorer was fitted or calibrated on (not held out)."""
    if not DEFAULT_SCORER.exists():
        return ()
    card = load_scorer().card
    return tuple(card.get("training_generators", [])) + tuple(
        card.get("calibration_generators", [])
    )


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -50, 50)))


def logit_of(p: float) -> float:
    p = min(max(p, 1e-9), 1 - 1e-9)
    return math.log(p / (1 - p))
