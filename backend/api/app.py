"""The FastAPI application."""

import ctypes
import multiprocessing
import os
import signal
import sys

from fastapi import APIRouter, FastAPI
from sqlalchemy.orm import sessionmaker

from backend.api.body_limits import BodyLimitMiddleware
from backend.api.log_redaction import redact_access_logs
from backend.api.routes import (
    alerts,
    api_docs,
    auth,
    comparisons,
    detection_cells,
    detection_feedback,
    frontend,
    health,
    job_events,
    jobs,
    languages,
    measurements,
    methods,
    models,
    ogc,
    organisations,
    products,
    reports,
    schedules,
    site_gis,
    sites,
    stac,
    survey_sources,
    surveys,
    tiles,
    tokens,
    uploads,
    users,
)
from backend.api.security_headers import SecurityHeadersMiddleware
from backend.config import Settings, get_settings
from backend.db.session import make_engine
from backend.storage import LocalStorage
from backend.urls import API_PREFIX
from backend.wiring import wire
from worker.celery_app import create_celery

PR_SET_PDEATHSIG = 1  # prctl(2)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    wire(settings)
    redact_access_logs()
    app = FastAPI(
        # /docs is served by api_docs, from a package rather than FastAPI's CDN.
        docs_url=None,
        redoc_url=None,
        title="slidewatch",
        version="0.1.0",
        summary="Landslide detection from multi-temporal drone surveys.",
        description="Every endpoint but `/health` needs an API token: "
        "`Authorization: Bearer <token>` (create one with `slidewatch create-token`), or, "
        "for GIS clients that cannot send headers, `?api_key=<token>` (slidewatch keeps it out "
        "of its access log and of the links it returns; proxies may log it: prefer the "
        "header). GIS users: OGC API – Features at `/ogc`, "
        f"STAC at `/stac/catalog.json`, map tiles and WMTS under `{API_PREFIX}/sites/{{id}}`.",
    )
    engine = make_engine(settings.resolved_database_url)
    app.state.settings = settings
    app.state.engine = engine
    app.state.sessionmaker = sessionmaker(bind=engine, expire_on_commit=False)
    app.state.storage = LocalStorage(settings.storage_dir)
    app.state.celery = create_celery(settings)
    app.add_middleware(BodyLimitMiddleware, limit=settings.max_request_bytes)
    # Added last, so outermost: every answer gets the headers, errors of the others too.
    app.add_middleware(SecurityHeadersMiddleware, settings=settings)

    app.include_router(health.router)
    api = APIRouter(prefix=API_PREFIX)
    for module in (
        sites,
        survey_sources,
        surveys,
        comparisons,
        jobs,
        products,
        tiles,
        alerts,
        schedules,
        reports,
        site_gis,
        auth,
        tokens,
        users,
        organisations,
        uploads,
        job_events,
        detection_feedback,
        detection_cells,
        measurements,
        models,
        methods,
        languages,
    ):
        api.include_router(module.router)
    app.include_router(api)
    app.include_router(ogc.router)
    app.include_router(stac.router)
    app.include_router(frontend.router)
    api_docs.mount_docs(app)
    frontend.mount_frontend(app, settings)
    return app


def create_served_app() -> FastAPI:
    """The app of one process of `slidewatch api`. With several processes uvicorn's parent
    only supervises them; should it be killed outright (SIGKILL, nothing it can catch), its
    processes would go on serving the port unsupervised, and a `slidewatch run` that starts
    the API again could not bind it. So each asks the kernel for SIGTERM when its parent
    dies."""
    if multiprocessing.parent_process() is not None and sys.platform == "linux":
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != multiprocessing.parent_process().pid:  # type: ignore[union-attr]
            os.kill(os.getpid(), signal.SIGTERM)  # the parent died before we asked
    return create_app()
