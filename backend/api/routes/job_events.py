"""A job's progress pushed to the page as Server-Sent Events.

    GET /sites/{site_id}/jobs/{job_id}/events     text/event-stream

Each change of the job (state, a stage's state or progress, an error) is sent as
`event: job` whose data is the job as `GET .../jobs/{job_id}` gives it; the stream ends
after the job has succeeded or failed. Comment lines keep idle connections open through
proxies. The job table is the source: workers write their progress there.
"""

import asyncio
import json
from collections.abc import AsyncIterator

from fastapi import APIRouter, Request
from fastapi.responses import StreamingResponse
from sqlalchemy.orm import sessionmaker
from starlette.concurrency import run_in_threadpool

from backend.api.access import SiteViewer
from backend.api.deps import SessionDep
from backend.api.routes.jobs import job_of_site
from backend.api.serializers import job_out
from backend.db.models import Job, JobState
from backend.ids import RowId

router = APIRouter(prefix="/sites/{site_id}/jobs", tags=["jobs"])

POLL_S = 0.5
KEEP_ALIVE_S = 15.0
RECONNECT_MS = 2000
FINAL_STATES = (JobState.succeeded, JobState.failed)


def _job_json(make_session: sessionmaker, job_id: RowId) -> tuple[str, bool]:
    with make_session() as session:
        job = session.get(Job, job_id)
        if job is None:
            return json.dumps({"id": job_id, "state": "deleted"}), True
        out = job_out(job)
        return out.model_dump_json(), out.state in FINAL_STATES


async def job_events(
    request: Request, make_session: sessionmaker, job_id: RowId
) -> AsyncIterator[str]:
    yield f"retry: {RECONNECT_MS}\n\n"
    last, quiet, sent = None, 0.0, 0
    while not await request.is_disconnected():
        data, final = await run_in_threadpool(_job_json, make_session, job_id)
        if data != last:
            sent += 1
            yield f"id: {sent}\nevent: job\ndata: {data}\n\n"
            last, quiet = data, 0.0
        elif quiet >= KEEP_ALIVE_S:
            yield ": still working\n\n"
            quiet = 0.0
        if final:
            return
        await asyncio.sleep(POLL_S)
        quiet += POLL_S


@router.get(
    "/{job_id}/events",
    summary="The job's progress as Server-Sent Events, until it succeeds or fails",
    response_class=StreamingResponse,
    responses={200: {"content": {"text/event-stream": {}}}},
)
def stream_job_events(
    job_id: RowId, request: Request, site: SiteViewer, session: SessionDep
) -> StreamingResponse:
    job_of_site(session, site, job_id)
    session.rollback()  # hold no transaction while the stream lasts (it reads on its own)
    return StreamingResponse(
        job_events(request, request.app.state.sessionmaker, job_id),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
    )
