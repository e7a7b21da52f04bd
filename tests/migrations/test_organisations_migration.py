"""The migration to organisations keeps today's data in one default organisation."""

import pytest
from sqlalchemy import text

from backend.db.migrate import upgrade
from backend.db.session import make_engine


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request: pytest.FixtureRequest) -> str:
    fixture = "sqlite_url" if request.param == "sqlite" else "postgres_url"
    return request.getfixturevalue(fixture)


def test_sites_users_and_tokens_of_before_go_to_the_default_organisation(
    database_url: str,
) -> None:
    upgrade(database_url, "0010")
    engine = make_engine(database_url)
    try:
        with engine.begin() as connection:
            connection.execute(
                text(
                    "INSERT INTO sites (name, description, timezone, created_at) "
                    "VALUES ('East flank', '', 'UTC', CURRENT_TIMESTAMP)"
                )
            )
            connection.execute(
                text(
                    "INSERT INTO users (username, display_name, password_hash, created_at) "
                    "VALUES ('maria', '', 'x', CURRENT_TIMESTAMP)"
                )
            )
            connection.execute(
                text(
                    "INSERT INTO api_tokens (name, token_hash, prefix, created_at, kind) "
                    "VALUES ('ops', 'h', 'sw_x', CURRENT_TIMESTAMP, 'api')"
                )
            )
        upgrade(database_url)
        with engine.connect() as connection:
            [(org_id, name)] = connection.execute(text("SELECT id, name FROM organisations")).all()
            assert name == "Default organisation"
            assert connection.execute(text("SELECT organisation_id FROM sites")).all() == [
                (org_id,)
            ]
            assert connection.execute(
                text("SELECT organisation_id, role FROM memberships")
            ).all() == [(org_id, "admin")]
            # The API token of before stays the platform administrator's.
            assert connection.execute(
                text("SELECT organisation_id, role, site_id FROM api_tokens")
            ).all() == [(None, None, None)]
    finally:
        engine.dispose()
