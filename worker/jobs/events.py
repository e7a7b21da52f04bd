"""What the job layer tells the rest of the platform, without depending on it.

The job layer sits below the services (it depends on the domain and the library only), so
a service that reacts to a job (alerts when a comparison finds landslides or a job fails)
subscribes here, and each process's composition root wires it (`backend.wiring`, called by
the API app factory and the Celery worker). Each listener runs in a savepoint: a broken
listener never undoes the job's own update.
"""

import logging
from collections.abc import Callable
from enum import StrEnum
from typing import Any

from sqlalchemy.orm import Session

from backend.config import Settings

log = logging.getLogger(__name__)
Listener = Callable[[Session, Any, Settings], Any]


class JobEvent(StrEnum):
    comparison_succeeded = "comparison_succeeded"  # the listener gets the Comparison
    survey_ready = "survey_ready"  # reconstructed; the listener gets the Survey
    job_failed = "job_failed"  # the listener gets the Job
    report_ready = "report_ready"  # the listener gets the Report


_listeners: dict[JobEvent, list[Listener]] = {event: [] for event in JobEvent}


def subscribe(event: JobEvent, listener: Listener) -> None:
    """Call `listener(session, subject, settings)` on `event` (subscribing twice has no
    effect); `settings` are those of the process that publishes."""
    if listener not in _listeners[event]:
        _listeners[event].append(listener)


def publish(event: JobEvent, settings: Settings, session: Session, subject: Any) -> None:
    for listener in list(_listeners[event]):
        try:
            with session.begin_nested():
                listener(session, subject, settings)
        except Exception:
            name = getattr(listener, "__name__", repr(listener))
            log.exception("listener %s of %s failed", name, event)
