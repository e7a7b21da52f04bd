"""The detection model registry: database rows over the library's weights and model cards.

A row (ModelVersion) points at a weights file and copies its model card. The model that
ships in the package is registered on first use (`ensure_shipped_model`); models trained
by the platform (backend/services/training.py) live in storage under `models/`. At most
one row is the default: what a cnn comparison runs when its parameters name no model.

Comparisons refer to models as "name@version" (kept in their parameters, so a comparison
says which model it ran); only the worker turns that into a file path (`card_path`).
Paths given by API users are never opened: a model must be registered first.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

from sqlalchemy import select, update
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.orm import Session

from backend.db.models import ModelVersion
from backend.storage import LocalStorage
from worker.pipeline.cnn.options import PACKAGE_WEIGHTS, default_model_path

PACKAGE, STORAGE = "package", "storage"


class UnknownModel(LookupError):
    """The model reference names no registered model."""


def reference(row: ModelVersion) -> str:
    return f"{row.name}@{row.version}"


def _read_card(card_path: Path) -> dict:
    return json.loads(Path(card_path).read_text(encoding="utf-8"))


def register_model(
    session: Session, card_path: Path, location: str, weights_path: str, make_default: bool
) -> ModelVersion:
    """Add (or return the existing) row for the model whose card is at `card_path`.

    `weights_path` is relative to the package weights folder or to the storage root, as
    `location` says. With `make_default` the row becomes the only default.
    """
    card = _read_card(card_path)
    values = {
        "name": card["name"],
        "version": card["version"],
        "kind": card["kind"],
        "location": location,
        "weights_path": weights_path,
        "weights_sha256": card["weights_sha256"],
        "card": card,
        "is_default": False,
        "created_at": datetime.now(UTC),
    }
    # INSERT .. ON CONFLICT DO NOTHING: the API and a worker may register the shipped
    # model at the same moment; both dialects the platform runs on support it.
    insert = sqlite_insert if session.get_bind().dialect.name == "sqlite" else pg_insert
    session.execute(
        insert(ModelVersion)
        .values(**values)
        .on_conflict_do_nothing(index_elements=["name", "version"])
    )
    row = session.scalar(
        select(ModelVersion).where(
            ModelVersion.name == card["name"], ModelVersion.version == card["version"]
        )
    )
    if make_default and not row.is_default:
        session.execute(update(ModelVersion).values(is_default=False))
        row.is_default = True
    session.flush()
    return row


def ensure_shipped_model(session: Session) -> ModelVersion | None:
    """Register the package's default model (idempotent); it becomes the default when no
    row is. None when the package ships no weights."""
    card_path = default_model_path()
    if card_path is None:
        return None
    card = _read_card(card_path)
    has_default = session.scalar(select(ModelVersion.id).where(ModelVersion.is_default)) is not None
    return register_model(
        session, card_path, PACKAGE, card["weights_file"], make_default=not has_default
    )


def list_models(session: Session) -> list[ModelVersion]:
    ensure_shipped_model(session)
    return list(session.scalars(select(ModelVersion).order_by(ModelVersion.id)))


def default_model(session: Session) -> ModelVersion | None:
    ensure_shipped_model(session)
    return session.scalar(select(ModelVersion).where(ModelVersion.is_default))


def find_model(session: Session, ref: str) -> ModelVersion:
    """The row named by "name@version" (or "name": its newest version)."""
    ensure_shipped_model(session)
    name, _, version = ref.partition("@")
    query = select(ModelVersion).where(ModelVersion.name == name)
    if version:
        query = query.where(ModelVersion.version == version)
    row = session.scalar(query.order_by(ModelVersion.id.desc()).limit(1))
    if row is None:
        raise UnknownModel(f"no registered detection model {ref!r}")
    return row


def card_path(row: ModelVersion, storage: LocalStorage) -> Path:
    """The absolute path of the model's card (next to its weights)."""
    if row.location == PACKAGE:
        weights = PACKAGE_WEIGHTS / row.weights_path
    else:
        weights = storage.absolute(row.weights_path)
    return weights.with_suffix(".json")


__all__ = [
    "PACKAGE",
    "STORAGE",
    "UnknownModel",
    "card_path",
    "default_model",
    "ensure_shipped_model",
    "find_model",
    "list_models",
    "reference",
    "register_model",
]
