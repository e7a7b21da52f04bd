"""New test databases at the head revision.

Migrating a database from empty takes about half a second, and some three hundred tests
each start on a new one. So each kind is migrated once per run, and copied: a SQLite
file with SQLite's backup (page for page), a PostgreSQL database as a copy of a template
database (CREATE DATABASE ... TEMPLATE). Either copy has the schema and rows `upgrade`
makes. Running the migrations themselves, from empty and back, is what tests/migrations
tests, on both databases.
"""

import atexit
import os
import sqlite3
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path

from sqlalchemy import create_engine, inspect
from sqlalchemy.engine import URL, make_url

from backend.db.migrate import upgrade

TEST_DATABASE_URL = os.environ.get(
    "SLIDEWATCH_TEST_DATABASE_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres"
)


_folders: list[tempfile.TemporaryDirectory] = []  # removed when the run ends


@cache
def _sqlite_at_head() -> Path:
    _folders.append(tempfile.TemporaryDirectory(prefix="slidewatch-migrated-"))
    path = Path(_folders[-1].name) / "head.db"
    upgrade(f"sqlite:///{path}")
    return path


@cache
def _postgresql_at_head() -> str:
    """A database at the head revision on the test server, dropped when the run ends."""
    name = f"slidewatch_test_head_{uuid.uuid4().hex[:12]}"
    admin = create_engine(TEST_DATABASE_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.exec_driver_sql(f'CREATE DATABASE "{name}"')
    upgrade(make_url(TEST_DATABASE_URL).set(database=name).render_as_string(hide_password=False))

    def drop() -> None:
        with admin.connect() as connection:
            connection.exec_driver_sql(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        admin.dispose()

    atexit.register(drop)
    return name


def _is_empty(url: URL) -> bool:
    engine = create_engine(url)
    try:
        with engine.connect() as connection:
            return not inspect(connection).get_table_names()
    finally:
        engine.dispose()


def migrate_new_database(url: str) -> None:
    """Bring the new, empty database at `url` to the head revision, as `upgrade` does."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "postgresql" and parsed.database and _is_empty(parsed):
        template = _postgresql_at_head()
        admin = create_engine(TEST_DATABASE_URL, isolation_level="AUTOCOMMIT")
        try:
            with admin.connect() as connection:
                connection.exec_driver_sql(f'DROP DATABASE "{parsed.database}" WITH (FORCE)')
                connection.exec_driver_sql(
                    f'CREATE DATABASE "{parsed.database}" TEMPLATE "{template}"'
                )
        finally:
            admin.dispose()
        return
    if parsed.get_backend_name() != "sqlite" or not parsed.database:
        upgrade(url)
        return
    target = Path(parsed.database)
    if target.exists() and target.stat().st_size > 0:
        upgrade(url)  # not new: migrate what is there
        return
    source, destination = sqlite3.connect(_sqlite_at_head()), sqlite3.connect(target)
    try:
        source.backup(destination)
    finally:
        source.close()
        destination.close()


@contextmanager
def empty_postgres_database() -> Iterator[str]:
    """The URL of a new empty database on the test PostgreSQL server, dropped afterwards."""
    admin = create_engine(TEST_DATABASE_URL, isolation_level="AUTOCOMMIT")
    name = f"slidewatch_test_{uuid.uuid4().hex[:12]}"
    with admin.connect() as connection:
        connection.exec_driver_sql(f'CREATE DATABASE "{name}"')
    try:
        yield make_url(TEST_DATABASE_URL).set(database=name).render_as_string(hide_password=False)
    finally:
        with admin.connect() as connection:
            connection.exec_driver_sql(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        admin.dispose()
