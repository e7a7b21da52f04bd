"""Queueing the rendering ahead of map tiles (backend/services/tile_prerender.py renders
them): a survey ready or a comparison succeeded sends a task once its session commits.

Kept apart from the rendering so that the processes that only queue (the API's routes, every
worker through the job events) do not import the tile renderer (rio-tiler, with xarray and
pandas: over a second) when they start.
"""

from __future__ import annotations

import logging

from sqlalchemy import event
from sqlalchemy.orm import Session

from backend.config import Settings
from backend.db.models import Comparison, Survey

log = logging.getLogger(__name__)


def send_prerender_task(settings: Settings, owner: str, owner_id: int) -> None:
    """Queue the rendering ahead of a survey's or a comparison's tiles (nothing when it is
    turned off). A broker that cannot be reached costs renders later, not this request."""
    if settings.tile_prerender_max_tiles <= 0 or settings.tile_disk_cache_bytes <= 0:
        return
    from worker.celery_app import QUEUE, TILE_PRERENDER_TASK, client_for

    try:
        client_for(settings).send_task(TILE_PRERENDER_TASK, args=[owner, owner_id, 0], queue=QUEUE)
    except Exception as exc:
        log.warning("tiles of %s %s not queued for rendering ahead: %s", owner, owner_id, exc)


def queue_after_commit(session: Session, settings: Settings, owner: str, owner_id: int) -> None:
    """Queue the rendering ahead once `session` commits (never for a rolled-back one): the
    worker must find the survey ready, the comparison succeeded."""
    pending: list[tuple[str, int]] = session.info.setdefault("prerenders_to_queue", [])
    session.info["prerenders_settings"] = settings
    if not session.info.get("prerenders_listener"):
        event.listen(session, "after_commit", _queue_pending)
        event.listen(session, "after_rollback", _forget_pending)
        session.info["prerenders_listener"] = True
    pending.append((owner, owner_id))


def _queue_pending(session: Session) -> None:
    pending = session.info.pop("prerenders_to_queue", [])
    settings = session.info.get("prerenders_settings")
    for owner, owner_id in pending:
        send_prerender_task(settings, owner, owner_id)


def _forget_pending(session: Session) -> None:
    session.info.pop("prerenders_to_queue", None)


def comparison_succeeded(session: Session, comparison: Comparison, settings: Settings) -> None:
    """Job event listener: render the comparison's tiles ahead."""
    queue_after_commit(session, settings, "comparisons", comparison.id)


def survey_ready(session: Session, survey: Survey, settings: Settings) -> None:
    """Job event listener: render the survey's tiles ahead."""
    queue_after_commit(session, settings, "surveys", survey.id)
