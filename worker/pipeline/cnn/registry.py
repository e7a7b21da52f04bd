"""File-side model registry: a weights file plus a JSON model card per model.

A registered model is two files in a registry folder:

    <name>.pt    torch.save({"kind", "config", "state_dict"}); loaded with weights_only=True
    <name>.json  the model card (see `ModelCard`)

The card records what the model is (kind, config, input normalisation), how it was
trained (protocol, hyper-parameters, seed, epochs), on what data (the dataset manifest's
summary, with the `interim` flag when the DSMs were not produced by the reconstruction),
its metrics, the decision rule used at inference, and the SHA-256 of the weights file so
that a card and its weights cannot be mixed up. The database rows of the platform's
registry point at these files (added by the platform).

The default model ships inside the package in `worker/pipeline/cnn/weights/`.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from worker.pipeline.atomic import atomic_path, write_text_atomic
from worker.pipeline.cnn.models import build_model
from worker.pipeline.cnn.options import DEFAULT_MODEL_NAME, PACKAGE_WEIGHTS, default_model_path
from worker.pipeline.errors import InputError

__all__ = [
    "DEFAULT_MODEL_NAME",
    "PACKAGE_WEIGHTS",
    "LoadedModel",
    "ModelCard",
    "default_model_path",
    "list_models",
    "load_default_model",
    "load_model",
    "publish_model",
    "resolve_model",
    "save_model",
]


@dataclass
class ModelCard:
    name: str
    version: str
    kind: str  # "patchnet" or "slidenet"
    config: dict[str, Any]
    description: str = ""
    normalization: dict[str, Any] = field(default_factory=dict)
    decision: dict[str, Any] = field(default_factory=dict)  # thresholds used at inference
    training: dict[str, Any] = field(default_factory=dict)
    data: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    interim: bool = False  # trained on stand-in data (see data)
    created_at: str = ""
    weights_file: str = ""
    weights_sha256: str = ""
    parameters: int = 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelCard:
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in data.items() if k in known})


@dataclass
class LoadedModel:
    model: nn.Module
    card: ModelCard
    path: Path

    @property
    def version(self) -> str:
        return f"{self.card.name}@{self.card.version}"


def save_model(model: nn.Module, card: ModelCard, folder: Path) -> Path:
    """Write `<card.name>.pt` and `<card.name>.json` into `folder` atomically; returns the
    card path. Fills weights_file, weights_sha256 and parameters in the card."""
    folder = Path(folder)
    weights = folder / f"{card.name}.pt"
    buffer = io.BytesIO()
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    torch.save({"kind": card.kind, "config": card.config, "state_dict": state}, buffer)
    data = buffer.getvalue()
    with atomic_path(weights) as tmp:
        tmp.write_bytes(data)
    card.weights_file = weights.name
    card.weights_sha256 = hashlib.sha256(data).hexdigest()
    card.parameters = sum(p.numel() for p in model.parameters())
    card_path = folder / f"{card.name}.json"
    write_text_atomic(card_path, json.dumps(card.to_dict(), indent=2, sort_keys=True))
    return card_path


def load_model(path: Path) -> LoadedModel:
    """Load a model from its card (`.json`) or weights (`.pt`) path, in eval mode.

    The weights' SHA-256 must match the card's.
    """
    path = Path(path)
    card_path = path.with_suffix(".json")
    if not card_path.exists():
        raise InputError(f"no model card {card_path.name} next to the weights")
    card = ModelCard.from_dict(json.loads(card_path.read_text(encoding="utf-8")))
    weights = card_path.parent / (card.weights_file or f"{card.name}.pt")
    try:
        data = weights.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read the model weights {weights}: {exc}") from exc
    if card.weights_sha256 and hashlib.sha256(data).hexdigest() != card.weights_sha256:
        raise InputError(f"the weights {weights.name} do not match their model card")
    payload = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    model = build_model(payload["kind"], payload["config"])
    model.load_state_dict(payload["state_dict"])
    model.eval()
    return LoadedModel(model=model, card=card, path=weights)


def publish_model(
    card_path: Path,
    folder: Path,
    name: str,
    notes: str = "",
    benchmark: dict | None = None,
    decision: dict | None = None,
) -> Path:
    """Copy a registered model into another registry folder under a new name (e.g. the
    package's default); the card keeps everything else and records where it came from.
    `decision` updates the decision rule (e.g. a calibrated min_score). Also writes
    `<name>.md`, the card in words."""
    loaded = load_model(card_path)
    card = ModelCard.from_dict(loaded.card.to_dict())
    card.training = {**card.training, "published_from": f"{loaded.card.name}@{loaded.card.version}"}
    if decision:
        card.decision = {**card.decision, **decision}
    if notes:
        card.description = f"{card.description} {notes}".strip()
    if benchmark:
        card.metrics = {**card.metrics, "benchmark": benchmark}
    card.name = name
    path = save_model(loaded.model, card, folder)
    write_text_atomic(Path(folder) / f"{name}.md", model_card_markdown(card))
    for suffix in (".pt", ".json", ".md"):  # package files are world-readable
        (Path(folder) / f"{name}{suffix}").chmod(0o644)
    return path


def model_card_markdown(card: ModelCard) -> str:
    """A short human-readable model card."""
    data = card.data or {}
    training = card.training or {}
    validation = (card.metrics or {}).get("validation", {})
    lines = [
        f"# Model card: {card.name} ({card.kind})",
        "",
        f"Version {card.version}, created {card.created_at}; weights `{card.weights_file}` "
        f"(SHA-256 `{card.weights_sha256[:16]}…`), {card.parameters} parameters.",
        "",
        card.description,
        "",
        "## Intended use",
        "Landslide detection between two co-registered DSMs of the same site (the `cnn` "
        "method of slidewatch's comparison), at any pixel size: inputs are in pixel-size "
        "units. Not validated on real surveys yet.",
        "",
        "## Training data",
        f"{data.get('name', '?')}: {data.get('description', '')}",
        f"DSM source: {data.get('dsm_source', '?')}.",
    ]
    if data.get("augmentation_parts"):
        lines += [
            "",
            f"Augmentation: {', '.join(data['augmentation_parts'])}: simulator truth DSMs "
            "degraded by a reconstruction-noise model, so that DSMs with other artefacts "
            "than slidewatch's reconstruction do not raise false alarms.",
        ]
    if card.interim and data.get("interim_parts"):
        lines += [
            "",
            f"**Partly interim**: {', '.join(data['interim_parts'])} are simulator truth "
            "DSMs degraded by a reconstruction-noise model (docs/detection.md); the rest "
            "are slidewatch's reconstructions of simulated survey video.",
        ]
    elif card.interim:
        lines += [
            "",
            "**Interim**: trained on simulator truth DSMs degraded by a reconstruction-noise "
            "model, not on DSMs reconstructed from simulated video (docs/detection.md).",
        ]
    lines += [
        "",
        "## Training",
        f"Protocol: {training.get('protocol', '?')}; seed {training.get('seed')}; "
        f"held out: {training.get('exclude')}.",
        "",
        "## Input normalisation",
        json.dumps(card.normalization),
        "",
        "## Decision rule",
        json.dumps(card.decision),
        "",
        "## Metrics",
        f"Validation: best patch F1 {validation.get('best_f1', validation.get('f1', '?'))}.",
    ]
    bench = (card.metrics or {}).get("benchmark")
    if bench:
        lines += [
            "",
            "Benchmark (patch-wise F1 per pattern):",
            "",
            "```",
            json.dumps(bench, indent=1),
            "```",
        ]
    return "\n".join(lines) + "\n"


def list_models(folder: Path) -> list[ModelCard]:
    """The cards of every model in a registry folder, by name."""
    cards = []
    for card_path in sorted(Path(folder).glob("*.json")):
        try:
            data = json.loads(card_path.read_text(encoding="utf-8"))
        except ValueError:
            continue
        if "kind" in data and "weights_file" in data:
            cards.append(ModelCard.from_dict(data))
    return cards


_DEFAULT_CACHE: dict[str, LoadedModel] = {}


def load_default_model() -> LoadedModel:
    """The shipped default model (cached per process)."""
    path = default_model_path()
    if path is None:
        raise InputError("no default detection model ships with this installation")
    key = str(path)
    if key not in _DEFAULT_CACHE:
        _DEFAULT_CACHE[key] = load_model(path)
    return _DEFAULT_CACHE[key]


def resolve_model(name_or_path: str | None) -> LoadedModel:
    """None or "default": the shipped model; a path to a card or weights file otherwise."""
    if not name_or_path or name_or_path == "default":
        return load_default_model()
    path = Path(name_or_path)
    if not path.suffix:
        path = PACKAGE_WEIGHTS / f"{name_or_path}.json"
    if not path.exists():
        raise InputError(f"unknown detection model {name_or_path!r}")
    return load_model(path)
