"""What a job needs from the process that runs it: settings, storage, database sessions.

Built once by the process's composition root (the Celery worker in worker/tasks.py, a
test) with `JobContext.from_settings`, and passed to the stage runner, which hands it to
the job kinds; nothing in the job layer reads settings on its own.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from sqlalchemy.orm import Session, sessionmaker

from backend.config import Settings
from backend.db.session import make_engine, session_scope
from backend.storage import LocalStorage


@dataclass(frozen=True)
class JobContext:
    settings: Settings
    sessions: sessionmaker[Session]
    storage: LocalStorage

    @classmethod
    def from_settings(
        cls, settings: Settings, sessions: sessionmaker[Session] | None = None
    ) -> JobContext:
        """The context of `settings`; `sessions` when the process has its factory already."""
        if sessions is None:
            engine = make_engine(settings.resolved_database_url)
            sessions = sessionmaker(bind=engine, expire_on_commit=False)
        return cls(settings, sessions, LocalStorage(settings.storage_dir))

    @contextmanager
    def session_scope(self) -> Iterator[Session]:
        with session_scope(self.sessions) as session:
            yield session
