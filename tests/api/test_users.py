"""Users sign in to the map with a password; their token expires and can be ended."""

from datetime import UTC, datetime, timedelta

import pytest
from click.testing import CliRunner
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select, update

from backend.cli import main
from backend.db.models import ApiToken, User
from backend.passwords import hash_password, verify_password
from backend.services.users import UserRejected, create_user


@pytest.fixture
def user(app: FastAPI) -> dict[str, str]:
    with app.state.sessionmaker() as session:
        create_user(session, "maria", "landslide-2026", "Maria Rossi")
        session.commit()
    return {"username": "maria", "password": "landslide-2026"}


def test_passwords_are_stored_as_salted_scrypt_hashes(app: FastAPI, user: dict) -> None:
    with app.state.sessionmaker() as session:
        stored = session.scalars(select(User)).one().password_hash
    assert stored.startswith("scrypt$16384$8$1$") and user["password"] not in stored
    assert verify_password(user["password"], stored)
    assert not verify_password("landslide-2027", stored)
    assert hash_password(user["password"]) != stored  # a new salt each time


def test_sign_in_gives_a_token_that_opens_the_api(client: TestClient, user: dict) -> None:
    response = client.post("/api/v1/auth/sign-in", json=user)
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["user"] == {"id": 1, "username": "maria", "display_name": "Maria Rossi"}
    headers = {"Authorization": f"Bearer {body['token']}"}
    assert client.get("/api/v1/sites", headers=headers).status_code == 200
    me = client.get("/api/v1/auth/me", headers=headers).json()
    assert me["kind"] == "user" and me["name"] == "maria" and me["expires_at"]


@pytest.mark.parametrize(
    "body",
    [{"username": "maria", "password": "wrong-password"}, {"username": "nobody", "password": "x"}],
)
def test_wrong_name_or_password_is_refused_alike(
    client: TestClient, user: dict, body: dict
) -> None:
    response = client.post("/api/v1/auth/sign-in", json=body)
    assert response.status_code == 401
    assert response.json()["detail"] == "wrong user name or password"


def test_sign_out_ends_the_session_and_says_an_api_token_is_revoked_instead(
    client: TestClient, user: dict, auth: dict
) -> None:
    token = client.post("/api/v1/auth/sign-in", json=user).json()["token"]
    headers = {"Authorization": f"Bearer {token}"}
    assert client.post("/api/v1/auth/sign-out", headers=headers).status_code == 204
    assert client.get("/api/v1/sites", headers=headers).status_code == 401
    # The platform's API tokens still sign in to the map; signing out with one does not
    # pretend to end it: it says how to revoke it.
    assert client.get("/api/v1/auth/me", headers=auth).json()["kind"] == "token"
    refused = client.post("/api/v1/auth/sign-out", headers=auth)
    assert refused.status_code == 409
    assert "DELETE /api/v1/auth/tokens/" in refused.json()["detail"]


def test_an_expired_session_is_refused(client: TestClient, app: FastAPI, user: dict) -> None:
    token = client.post("/api/v1/auth/sign-in", json=user).json()["token"]
    with app.state.sessionmaker() as session:
        session.execute(
            update(ApiToken)
            .where(ApiToken.user_id.is_not(None))
            .values(expires_at=datetime.now(UTC) - timedelta(seconds=1))
        )
        session.commit()
    response = client.get("/api/v1/sites", headers={"Authorization": f"Bearer {token}"})
    assert response.status_code == 401


@pytest.mark.parametrize(
    ("username", "password", "message"),
    [
        ("maria", "another-one", "exists"),
        ("../root", "long-enough", "user name must be"),
        ("luca", "short", "at least 8 characters"),
    ],
)
def test_bad_accounts_are_refused_in_plain_words(
    app: FastAPI, user: dict, username: str, password: str, message: str
) -> None:
    with app.state.sessionmaker() as session, pytest.raises(UserRejected, match=message):
        create_user(session, username, password)


def test_create_user_command(app: FastAPI) -> None:
    result = CliRunner().invoke(main, ["create-user", "luca", "--password", "pendio-franoso"])
    assert result.exit_code == 0, result.output
    assert "viewer of Default organisation" in result.output
    result = CliRunner().invoke(main, ["create-user", "luca", "--password", "pendio-franoso"])
    assert result.exit_code != 0 and "exists" in result.output
    analyst = ["create-user", "anna", "--password", "frana-attiva", "--role", "analyst"]
    assert "analyst of Default organisation" in CliRunner().invoke(main, analyst).output
    nowhere = ["create-user", "ugo", "--password", "frana-attiva", "--organisation", "Nowhere"]
    assert "no organisation named 'Nowhere'" in CliRunner().invoke(main, nowhere).output
