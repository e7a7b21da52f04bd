"""The Celery applications and the names of the queue and its tasks.

Two kinds of Celery app, one configuration (`celery_config`):

- `create_celery(settings)`: a client that sends tasks by name, made by the API's app
  factory, the CLI and the alert queueing from the settings they were given.
- `app`: the worker's app, on which the task modules register their tasks when they are
  imported; `celery --app worker.celery_app:app` runs it (backend/cli.py). It reads the
  SLIDEWATCH_* settings when Celery first needs its configuration, not at import: the API
  imports task names from these modules and must not read the environment through them.
"""

import logging

from celery import Celery

from backend.config import Settings, get_settings

RUN_STAGE_TASK = "slidewatch.run_stage"
RECOVER_TASK = "slidewatch.recover_stalled_jobs"
DELIVER_TASK = "slidewatch.deliver"
MONITORING_TICK_TASK = "slidewatch.monitoring_tick"
TILE_PRERENDER_TASK = "slidewatch.prerender_tiles"
QUEUE = "slidewatch"
# Reports and model training are jobs: their stages run as RUN_STAGE_TASK (worker.tasks).
TASK_MODULES = ["worker.tasks", "worker.tasks_monitoring", "worker.tasks_tiles"]


class QuietSweeps(logging.Filter):
    """Drops the INFO lines of the recovery sweep (sent, received, succeeded): beat sends it
    every few seconds, and three lines a sweep would bury the log people read. What the
    sweep finds is logged as a warning, which passes."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno > logging.INFO:
            return True
        message = record.getMessage()
        return RECOVER_TASK not in message and "recover-stalled-jobs" not in message


for _name in ("celery.beat", "celery.worker.strategy", "celery.app.trace"):
    logging.getLogger(_name).addFilter(QuietSweeps())


def transport_options(settings: Settings) -> dict[str, object]:
    if settings.broker_is_embedded:
        return {}  # the SQLite broker hands its options to SQLAlchemy's create_engine
    return {"visibility_timeout": settings.broker_visibility_timeout_s}


def celery_config(settings: Settings) -> dict[str, object]:
    return dict(
        broker_url=settings.resolved_broker_url,
        # A task is acknowledged only when it has finished, so a worker that dies
        # mid-stage does not take the message with it (Redis delivers it again after the
        # visibility timeout; the recovery sweep, worker/jobs/recovery.py, does not wait).
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_serializer="json",
        accept_content=["json"],
        task_ignore_result=True,  # job state lives in the database, not in a result backend
        task_default_queue=QUEUE,
        broker_connection_retry_on_startup=True,
        broker_transport_options=transport_options(settings),
        worker_hijack_root_logger=False,
        beat_schedule={
            # The sweep that queues again a killed worker's stage (worker/jobs/recovery.py)
            # runs on whichever worker is free. A sweep not started within its interval
            # is dropped unrun: the next one does its work, and sweeps sent while every
            # worker is busy with a long stage do not pile up in the queue.
            "recover-stalled-jobs": {
                "task": RECOVER_TASK,
                "schedule": float(settings.recovery_interval_s),
                "options": {"expires": float(settings.recovery_interval_s)},
            },
            # Due monitoring schedules are claimed in the database: a second or restarted
            # beat only sends more ticks, never a second run (backend/services/schedules.py).
            "monitoring-tick": {
                "task": MONITORING_TICK_TASK,
                "schedule": float(settings.schedule_tick_s),
                "options": {"expires": float(settings.schedule_tick_s)},  # as the sweep's
            },
        },
    )


def create_celery(settings: Settings) -> Celery:
    client = Celery("slidewatch", include=TASK_MODULES)
    client.config_from_object(celery_config(settings))
    return client


_clients: dict[str, Celery] = {}


def client_for(settings: Settings) -> Celery:
    """A client of the settings' broker, made once per broker in this process (each keeps
    its own connection pool)."""
    broker_url = settings.resolved_broker_url
    if broker_url not in _clients:
        _clients[broker_url] = create_celery(settings)
    return _clients[broker_url]


def _worker_config() -> dict[str, object]:
    # The worker process's composition root: its settings come from the environment.
    return celery_config(get_settings())


app = Celery("slidewatch", include=TASK_MODULES)
# A callable is a promise that Celery evaluates when it first loads the configuration
# (Celery.add_defaults); an invalid setting still stops the worker at start-up.
app.add_defaults(_worker_config)
