"""Sign-in that resists guessing, password rules, and the security headers of every answer."""

import re
from datetime import timedelta
from html.parser import HTMLParser
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from backend.api.security_headers import map_policy
from backend.db.models import SignInFailure
from backend.db.tokens import as_utc
from backend.services.users import UserRejected, create_user

REPO = Path(__file__).resolve().parents[2]
RIGHT = {"username": "maria", "password": "landslide-2026"}
WRONG = {"username": "maria", "password": "not-her-password"}


@pytest.fixture
def user(app: FastAPI) -> dict[str, str]:
    with app.state.sessionmaker() as session:
        create_user(session, RIGHT["username"], RIGHT["password"], "Maria Rossi")
        session.commit()
    return RIGHT


def _age_failures(app: FastAPI, seconds: float) -> None:
    """As if the failures happened `seconds` earlier (the window is what is tested)."""
    with app.state.sessionmaker() as session:
        for failure in session.scalars(select(SignInFailure)):
            failure.at = as_utc(failure.at) - timedelta(seconds=seconds)
        session.commit()


def test_an_account_is_locked_after_five_failures_even_for_the_right_password(
    client: TestClient, app: FastAPI, user: dict
) -> None:
    for _ in range(5):
        assert client.post("/api/v1/auth/sign-in", json=WRONG).status_code == 401
    locked = client.post("/api/v1/auth/sign-in", json=RIGHT)
    assert locked.status_code == 429
    assert 890 <= int(locked.headers["Retry-After"]) <= 900
    assert "too many failed sign-ins to the account 'maria'" in locked.json()["detail"]
    assert "locked until" in locked.json()["detail"]
    _age_failures(app, 901)  # the window has passed
    signed_in = client.post("/api/v1/auth/sign-in", json=RIGHT)
    assert signed_in.status_code == 200 and signed_in.json()["notice"] is None


def test_the_lock_opens_as_the_oldest_failure_leaves_the_window(
    client: TestClient, app: FastAPI, user: dict
) -> None:
    client.post("/api/v1/auth/sign-in", json=WRONG)
    _age_failures(app, 600)
    for _ in range(4):
        client.post("/api/v1/auth/sign-in", json=WRONG)
    locked = client.post("/api/v1/auth/sign-in", json=RIGHT)
    assert locked.status_code == 429 and 290 <= int(locked.headers["Retry-After"]) <= 300


def test_a_sign_in_after_failures_tells_the_person_about_them(
    client: TestClient, user: dict
) -> None:
    for _ in range(2):
        client.post("/api/v1/auth/sign-in", json=WRONG)
    notice = client.post("/api/v1/auth/sign-in", json=RIGHT).json()["notice"]
    assert notice.startswith("2 failed sign-ins to your account since ")
    assert "the last from testclient" in notice and "change your password" in notice
    assert client.post("/api/v1/auth/sign-in", json=RIGHT).json()["notice"] is None


def test_unknown_names_are_throttled_alike(client: TestClient, user: dict) -> None:
    nobody = {"username": "nobody", "password": "whatever-1"}
    answers = [client.post("/api/v1/auth/sign-in", json=nobody).status_code for _ in range(6)]
    assert answers == [401] * 5 + [429]


def test_an_address_is_locked_after_failures_on_many_accounts(
    client: TestClient, app: FastAPI, user: dict
) -> None:
    app.state.settings.sign_in_max_failures_per_address = 4
    for name in ("anna", "bruno", "carla", "dario"):
        client.post("/api/v1/auth/sign-in", json={"username": name, "password": "guess-1234"})
    locked = client.post("/api/v1/auth/sign-in", json=RIGHT)
    assert locked.status_code == 429 and "your address" in locked.json()["detail"]
    assert int(locked.headers["Retry-After"]) > 0


@pytest.mark.parametrize(
    ("password", "message"),
    [
        ("short", "at least 8 characters"),
        ("x" * 257, "at most 256 characters"),
        ("        ", "only spaces"),
        ("aaaaaaaaaa", "one character repeated"),
        ("Luca.Bianchi", "the user name"),
        ("Password123", "most common passwords"),
        ("12345678", "most common passwords"),
    ],
)
def test_passwords_that_are_easily_guessed_are_refused(
    app: FastAPI, password: str, message: str
) -> None:
    with app.state.sessionmaker() as session, pytest.raises(UserRejected, match=message):
        create_user(session, "luca.bianchi", password)


# --- headers ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("method", "path"),
    [
        ("GET", "/health"),
        ("GET", "/"),
        ("GET", "/app-config.json"),
        ("GET", "/api/v1/sites"),  # 401
        ("GET", "/api/v1/nowhere"),  # 404
        ("POST", "/api/v1/auth/sign-in"),  # 422
        ("GET", "/openapi.json"),
        ("GET", "/ogc"),
    ],
)
def test_every_answer_carries_the_security_headers(
    client: TestClient, method: str, path: str
) -> None:
    response = client.request(method, path)
    headers = response.headers
    assert headers["x-content-type-options"] == "nosniff"
    assert headers["x-frame-options"] == "DENY"
    assert headers["referrer-policy"] == "no-referrer"
    policy = headers["content-security-policy"]
    assert "script-src 'self';" in policy and "frame-ancestors 'none'" in policy
    assert "object-src 'none'" in policy and "connect-src 'self'" in policy
    assert "strict-transport-security" not in headers  # served over http here


def test_the_documentation_page_loads_nothing_from_elsewhere(client: TestClient) -> None:
    """/docs is Swagger UI served by the app: the map's strict policy, no CDN, no inline
    script; /redoc points to it."""
    page = client.get("/docs")
    policy = page.headers["content-security-policy"]
    assert "script-src 'self';" in policy and "frame-ancestors 'none'" in policy
    assert "http" not in policy.replace("'self'", "")
    assert "<script>" not in page.text and "cdn" not in page.text.lower()
    for asset in ("/docs/assets/swagger-ui-bundle.js", "/docs/api-docs.js"):
        assert client.get(asset).status_code == 200, asset
    assert client.get("/redoc", follow_redirects=False).headers["location"] == "/docs"


def test_the_basemap_origin_is_allowed_for_images() -> None:
    policy = map_policy("https://{s}.tile.openstreetmap.org/{z}/{x}/{y}.png")
    assert "img-src 'self' data: blob: https://*.tile.openstreetmap.org;" in policy
    assert "img-src 'self' data: blob: https://tiles.example:8443;" in map_policy(
        "https://tiles.example:8443/{z}/{x}/{y}.png"
    )


class _Scripts(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.inline: list[str] = []
        self.handlers: list[str] = []
        self._open_without_src = False

    def handle_starttag(self, tag: str, attrs: list) -> None:
        self.handlers += [name for name, _ in attrs if name.startswith("on")]
        self._open_without_src = tag == "script" and not dict(attrs).get("src")

    def handle_data(self, data: str) -> None:
        if self._open_without_src and data.strip():
            self.inline.append(data.strip())

    def handle_endtag(self, tag: str) -> None:
        self._open_without_src = False


@pytest.mark.parametrize("page", ["frontend/index.html", "frontend/dist/index.html"])
def test_the_page_has_no_inline_script(page: str) -> None:
    """What the policy's script-src 'self' needs (tests/e2e checks the browser reports no
    violation while the map is used)."""
    path = REPO / page
    assert path.is_file(), f"{page} is missing: build the map (make test does)"
    parser = _Scripts()
    parser.feed(path.read_text())
    assert parser.inline == [] and parser.handlers == []
    assert not re.search(r"javascript:", path.read_text(), re.IGNORECASE)
