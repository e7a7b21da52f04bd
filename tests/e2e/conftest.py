"""The map in a real browser: Debian's chromium driven by Playwright, against `slidewatch api`
and a real `slidewatch worker` on the embedded default (SQLite database and broker).

The map must be built first (`make test` does it: frontend/dist). Screenshots of every test
go to test-artifacts/e2e/; with SLIDEWATCH_DOCS_SCREENSHOTS=docs/images the documentation's
map pictures are written there too.
"""

import os
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Browser, Page, Playwright, expect, sync_playwright

from backend.config import Settings
from backend.db.migrate import upgrade
from backend.db.session import make_engine
from backend.services.users import create_user
from tests.api_helpers import join
from tests.integration.conftest import SlidewatchProcess
from worker.simulator.dsm_pair import DsmPairPaths, make_dsm_pair, write_dsm_pair

REPO = Path(__file__).resolve().parents[2]
# The built map: the app's own setting where given (a build made elsewhere), else frontend/dist.
FRONTEND_DIST = Path(os.environ.get("SLIDEWATCH_FRONTEND_DIR") or REPO / "frontend" / "dist")
ARTIFACTS = REPO / "test-artifacts" / "e2e"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
USER = {"username": "maria", "password": "landslide-2026"}
# Small requests, so that an upload of these small DSMs takes several and can be cut.
CHUNK_BYTES = 16 * 1024
LAPTOP = {"width": 1366, "height": 900}
# Two cores shared with a worker: give the page time rather than fail on a busy machine.
expect.set_options(timeout=20_000)


@dataclass(frozen=True)
class App:
    url: str
    settings: Settings
    api: SlidewatchProcess
    worker: SlidewatchProcess


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def app_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    """One server (API and worker) per test process, shared by the browser-test modules:
    each start costs tens of seconds on a loaded machine. The modules keep apart by their
    own site and user names."""
    if not (FRONTEND_DIST / "index.html").is_file():
        pytest.fail(
            "the map is not built: run `make test`, or `cd frontend && npm ci && npm run build`"
        )
    root = tmp_path_factory.mktemp("e2e")
    settings = Settings(data_dir=root / "data")
    settings.data_dir.mkdir()
    upgrade(settings.resolved_database_url)
    engine = make_engine(settings.resolved_database_url)
    with engine.begin() as connection:
        from sqlalchemy.orm import Session

        with Session(bind=connection) as session:
            user = create_user(session, USER["username"], USER["password"], "Maria Rossi")
            join(session, user.id, "admin")  # makes sites, uploads, compares, judges
            session.flush()
    engine.dispose()
    port = _free_port()
    extra = {
        "SLIDEWATCH_FRONTEND_DIR": str(FRONTEND_DIST),
        "SLIDEWATCH_UPLOAD_CHUNK_BYTES": str(CHUNK_BYTES),
        "SLIDEWATCH_SEED_DEMO": "false",
        # One browser at a time: a second API process would only cost its start.
        "SLIDEWATCH_API_WORKERS": "1",
        # The webhook receiver of the alerts test listens on loopback, which webhooks may
        # call only where an administrator allows it.
        "SLIDEWATCH_WEBHOOK_ALLOWED_NETWORKS": '["127.0.0.1/32"]',
    }
    worker = SlidewatchProcess(settings, root / "worker.log", ["worker", "--beat"], b" ready.")
    api = SlidewatchProcess(
        settings, root / "api.log", ["api", "--port", str(port)], b"Application startup complete"
    )
    for process in (worker, api):
        process.env.update(extra)
        process.launch()  # side by side: each takes seconds to import
    worker.wait_ready()
    api.wait_ready()
    try:
        yield App(f"http://127.0.0.1:{port}", settings, api, worker)
    finally:
        api.stop()
        worker.stop()


@pytest.fixture(scope="session")
def playwright() -> Iterator[Playwright]:
    with sync_playwright() as p:
        yield p


@pytest.fixture(scope="session")
def browser(playwright: Playwright, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Browser]:
    browser = playwright.chromium.launch(
        executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS
    )
    yield browser
    browser.close()


@pytest.fixture
def page(browser: Browser, request: pytest.FixtureRequest) -> Iterator[Page]:
    context = browser.new_context(viewport=LAPTOP, locale="en-GB", timezone_id="UTC")
    page = context.new_page()
    page.set_default_timeout(30_000)
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    # The page must live within its Content-Security-Policy: Chromium reports each
    # violation as a console error.
    page.on(
        "console",
        lambda message: (
            errors.append(message.text) if "Content Security Policy" in message.text else None
        ),
    )
    yield page
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"{request.node.name}-end.png"))
    context.close()
    assert not errors, f"errors in the page: {errors}"


def shot(page: Page, name: str, docs_name: str | None = None) -> None:
    """A screenshot as a test artifact; also into the docs when asked for."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"{name}.png"))
    docs = os.environ.get("SLIDEWATCH_DOCS_SCREENSHOTS")
    if docs and docs_name:
        target = REPO / docs / f"{docs_name}.png"
        target.parent.mkdir(parents=True, exist_ok=True)
        page.locator(".map-wrap").screenshot(path=str(target))  # the map alone


@pytest.fixture(scope="session")
def dsm_pair(tmp_path_factory: pytest.TempPathFactory) -> DsmPairPaths:
    """A seeded pre/post pair with a planted landslide and a 1.3 m × 0.7 m shift."""
    pair = make_dsm_pair(shape=(240, 240), pixel_size_m=1.0, shift_m=(1.3, -0.7, 0.2), seed=7)
    return write_dsm_pair(pair, tmp_path_factory.mktemp("e2e-pair"))


def compare_uploaded(
    api: httpx.Client, site_id: int, surveys: list[tuple[Path, str, str | None]]
) -> int:
    """Upload two DSM surveys (file, capture time, name) to a site over the API, compare
    them with `threshold` and wait for the comparison to succeed; its id."""
    ids = []
    for path, captured_at, name in surveys:
        params = {"captured_at": captured_at, "filename": path.name}
        if name is not None:
            params["name"] = name
        made = api.post(
            f"/sites/{site_id}/surveys",
            params=params,
            content=path.read_bytes(),
            headers={"Content-Type": "image/tiff"},
        )
        assert made.status_code == 201, made.text
        ids.append(made.json()["id"])
    created = api.post(
        f"/sites/{site_id}/comparisons",
        json={"pre_survey_id": ids[0], "post_survey_id": ids[1], "method": "threshold"},
    ).json()
    comparison = created["comparison"]["id"]
    deadline = time.monotonic() + 120
    while api.get(f"/sites/{site_id}/comparisons/{comparison}").json()["status"] != "succeeded":
        assert time.monotonic() < deadline, "the comparison did not finish"
        time.sleep(0.5)
    return comparison
