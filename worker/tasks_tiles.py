"""Celery task: render a survey's or a comparison's map tiles ahead, a chunk at a time
(backend/services/tile_prerender.py).

Each chunk renders for a few seconds, or until a job's stage waits, and then queues the
rest as a new message behind whatever came meanwhile: a long rendering never holds a
worker that a job needs. A chunk that gave way to a waiting stage comes back a little
later rather than at once, so that the stage is taken first.
"""

import logging
import time

from celery import Task

from worker.celery_app import QUEUE, TILE_PRERENDER_TASK, app
from worker.tasks import job_context

log = logging.getLogger(__name__)

# After giving way to a waiting stage: come back once it has been taken.
RESUME_AFTER_S = 2.0


@app.task(bind=True, name=TILE_PRERENDER_TASK)
def prerender_tiles(self: Task, owner: str, owner_id: int, start: int = 0) -> None:
    # Imported at the first chunk: the tile renderer (rio-tiler, xarray, pandas) takes over a
    # second to import, which every worker process would pay at its start.
    from backend.services.tile_prerender import describe, prerender_chunk

    context = job_context()
    settings = context.settings
    started = time.monotonic()
    with context.session_scope() as session:
        result = prerender_chunk(session, context.storage, settings, owner, owner_id, start)
    if result.gone:
        log.info("tiles of %s %s not rendered ahead: it is gone", owner, owner_id)
        return
    if start == 0 and result.done > 0:
        log.info("rendering tiles ahead: %s", describe(owner, owner_id, result.layers))
    log.info(
        "tiles of %s %s rendered ahead: %d of %d (%d rendered, %d already there, "
        "%d refused in %.1f s)%s",
        owner, owner_id, result.done, result.total, result.rendered, result.present,
        result.refused, time.monotonic() - started,
        "" if result.next_start is not None else ", done",
    )  # fmt: skip
    if result.next_start is not None:
        # Gave way (or used its time): the rest goes behind what was queued meanwhile.
        gave_way = result.rendered + result.present + result.refused == 0
        self.app.send_task(
            TILE_PRERENDER_TASK,
            args=[owner, owner_id, result.next_start],
            queue=QUEUE,
            countdown=RESUME_AFTER_S if gave_way else None,
        )
