"""Helpers of the GIS, alert and report tests: apps on either database, a live server,
seeded rows, and a finished comparison."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime

import pytest
import uvicorn
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.config import Settings, get_settings
from backend.db import session as db_session
from backend.db.models import (
    Comparison,
    Detection,
    JobState,
    Site,
    Survey,
    SurveyKind,
    SurveyStatus,
)
from backend.db.tokens import create_token
from tests.api_helpers import run_job_inline, upload_dsm
from tests.databases import migrate_new_database
from worker.simulator.dsm_pair import DsmPairPaths


@contextmanager
def app_for(settings: Settings, monkeypatch: pytest.MonkeyPatch) -> Iterator[FastAPI]:
    """An app on `settings`, with the worker-side code (which reads the environment) too."""
    monkeypatch.setenv("SLIDEWATCH_DATA_DIR", str(settings.data_dir))
    if settings.database_url:
        monkeypatch.setenv("SLIDEWATCH_DATABASE_URL", settings.database_url)
    for key, value in settings.model_dump(exclude_unset=True).items():
        if key not in ("data_dir", "database_url") and value is not None:
            text = json.dumps(value) if isinstance(value, list | dict) else str(value)
            monkeypatch.setenv(f"SLIDEWATCH_{key.upper()}", text)
    for cached in (get_settings, db_session.get_engine, db_session.get_sessionmaker):
        cached.cache_clear()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    migrate_new_database(settings.resolved_database_url)
    application = create_app(settings)
    try:
        yield application
    finally:
        application.state.engine.dispose()
        db_session.get_engine().dispose()
        for cached in (get_settings, db_session.get_engine, db_session.get_sessionmaker):
            cached.cache_clear()


def token_for(app: FastAPI) -> str:
    with app.state.sessionmaker() as session:
        token = create_token(session, "tests")
        session.commit()
    return token


class LiveServer:
    """The app served by uvicorn on a free local port, in a thread (for real clients)."""

    def __init__(self, app: FastAPI) -> None:
        self._socket = socket.socket()
        self._socket.bind(("127.0.0.1", 0))
        self.port = self._socket.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        # Where its users reach it: the links of its answers point here.
        app.state.settings.public_url = self.url
        config = uvicorn.Config(app, log_level="warning", lifespan="off")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(
            target=self.server.run, kwargs={"sockets": [self._socket]}, daemon=True
        )

    def __enter__(self) -> LiveServer:
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if time.monotonic() > deadline:
                raise RuntimeError("the live server did not start")
            time.sleep(0.05)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)
        self._socket.close()


def square(lon: float, lat: float, size: float = 0.0004) -> dict:
    """A small counter-clockwise square polygon (GeoJSON, lon/lat)."""
    ring = [[lon, lat], [lon + size, lat], [lon + size, lat + size], [lon, lat + size], [lon, lat]]
    return {"type": "Polygon", "coordinates": [ring]}


def seed_detections(app: FastAPI) -> dict[str, int]:
    """A site with two comparisons: 25 detections on a 5 × 5 grid observed 2026-07-01 and
    5 in a row observed 2026-08-01, these with 95 % intervals. Rows only (no files): for
    feature queries."""
    with app.state.sessionmaker() as session:
        site = Site(name="grid slope", description="seeded")
        session.add(site)
        session.flush()
        surveys = []
        for day in ("2026-06-01", "2026-07-01", "2026-08-01"):
            survey = Survey(
                site_id=site.id,
                name=f"flight {day}",
                captured_at=datetime.fromisoformat(f"{day}T10:00:00+00:00"),
                kind=SurveyKind.dsm,
                status=SurveyStatus.ready,
                crs="EPSG:32632",
                footprint=square(9.0, 46.0, 0.02),
                resolution_m=0.5,
            )
            session.add(survey)
            surveys.append(survey)
        session.flush()
        comparisons = []
        for pre, post in ((surveys[0], surveys[1]), (surveys[1], surveys[2])):
            comparison = Comparison(
                site_id=site.id,
                pre_survey_id=pre.id,
                post_survey_id=post.id,
                method="threshold",
                parameters={},
                status=JobState.succeeded,
                summary={},
                finished_at=datetime.now(UTC),
            )
            session.add(comparison)
            comparisons.append(comparison)
        session.flush()
        cells = [(i, j) for i in range(5) for j in range(5)]
        places = [(comparisons[0], 9.001 + 0.002 * i, 46.001 + 0.002 * j) for i, j in cells]
        places += [(comparisons[1], 9.011 + 0.002 * i, 46.015) for i in range(5)]
        for n, (comparison, lon, lat) in enumerate(places):
            session.add(
                Detection(
                    comparison_id=comparison.id,
                    geometry=square(lon, lat),
                    min_lon=lon,
                    min_lat=lat,
                    max_lon=lon + 0.0004,
                    max_lat=lat + 0.0004,
                    area_m2=100.0 + n,
                    volume_loss_m3=50.0 + n,
                    volume_gain_m3=40.0,
                    max_abs_dh_m=1.5,
                    score=0.8,
                    method="threshold",
                    # August's with their 95 % intervals, July's without (as cnn's are).
                    uncertainty=(
                        {
                            "area_m2_ci95": [90.0 + n, 112.0 + n],
                            "volume_loss_m3_ci95": [45.0 + n, 55.0 + n],
                            "volume_gain_m3_ci95": [36.0, 44.0],
                            "lod_m": 0.12,
                        }
                        if comparison is comparisons[1]
                        else None
                    ),
                )
            )
        session.commit()
        return {"site": site.id, "july": comparisons[0].id, "august": comparisons[1].id}


def finished_comparison(
    client: TestClient, auth: dict[str, str], pair: DsmPairPaths, name: str = "slope"
) -> dict[str, int]:
    """Upload the pair, compare it, run the job in this process; return the ids."""
    site = client.post("/api/v1/sites", json={"name": name}, headers=auth).json()["id"]
    pre = upload_dsm(client, auth, site, pair.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site, pair.post, "2026-07-01T10:00:00Z")
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": pre["id"], "post_survey_id": post["id"], "method": "threshold"},
        headers=auth,
    )
    assert created.status_code == 202, created.text
    run_job_inline(created.json()["job"]["id"])
    return {
        "site": site,
        "pre": pre["id"],
        "post": post["id"],
        "comparison": created.json()["comparison"]["id"],
        "job": created.json()["job"]["id"],
    }


def wait_until(predicate, timeout_s: float = 30.0, interval_s: float = 0.1):
    """Poll `predicate` until it returns something truthy; fail after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not reached within {timeout_s} s")
        time.sleep(interval_s)


class WebhookReceiver:
    """A local HTTP server that answers with the given status codes in turn (then 200),
    and keeps every request it got: headers and raw body."""

    def __init__(self, statuses: list[int] | None = None) -> None:
        import http.server

        self.statuses = list(statuses or [])
        self.requests: list[tuple[dict[str, str], bytes, float]] = []
        receiver = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                receiver.requests.append((dict(self.headers), body, time.monotonic()))
                code = receiver.statuses.pop(0) if receiver.statuses else 200
                self.send_response(code)
                self.end_headers()
                self.wfile.write(b"ok" if code == 200 else b"try later: db=10.0.0.5 token=t0p")

            def log_message(self, *args: object) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/hook"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def __enter__(self) -> WebhookReceiver:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.shutdown()
        self.server.server_close()


class MailReceiver:
    """A local SMTP server (aiosmtpd) that keeps every message it got."""

    def __init__(self) -> None:
        from aiosmtpd.controller import Controller

        self.messages: list = []
        receiver = self

        class Handler:
            async def handle_DATA(self, server, session, envelope):
                import email

                receiver.messages.append(email.message_from_bytes(envelope.content))
                return "250 OK"

        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        self.controller = Controller(Handler(), hostname="127.0.0.1", port=self.port)

    def __enter__(self) -> MailReceiver:
        self.controller.start()
        self.running = True
        return self

    def stop(self) -> None:
        if self.running:
            self.controller.stop()
            self.running = False

    def __exit__(self, *exc: object) -> None:
        self.stop()
