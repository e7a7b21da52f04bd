"""The Celery application. Configuration comes from the SLIDEWATCH_* settings."""

from celery import Celery

from backend.config import Settings, get_settings

RUN_STAGE_TASK = "slidewatch.run_stage"
RECOVER_TASK = "slidewatch.recover_stalled_jobs"
DELIVER_TASK = "slidewatch.deliver"
BUILD_REPORT_TASK = "slidewatch.build_report"
MONITORING_TICK_TASK = "slidewatch.monitoring_tick"
TRAIN_MODEL_TASK = "slidewatch.train_model"
QUEUE = "slidewatch"


def transport_options(settings: Settings) -> dict[str, object]:
    if settings.broker_is_embedded:
        return {}  # the SQLite broker hands its options to SQLAlchemy's create_engine
    return {"visibility_timeout": settings.broker_visibility_timeout_s}


def create_celery(settings: Settings) -> Celery:
    app = Celery(
        "slidewatch",
        broker=settings.resolved_broker_url,
        include=["worker.tasks", "worker.tasks_monitoring", "worker.tasks_training"],
    )
    app.conf.update(
        # A task is acknowledged only when it has finished, so a worker that dies
        # mid-stage leaves the message to be delivered again.
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
            "recover-stalled-jobs": {
                "task": RECOVER_TASK,
                "schedule": float(settings.recovery_interval_s),
            },
            # Due monitoring schedules are claimed in the database: a second or restarted
            # beat only sends more ticks, never a second run (backend/services/schedules.py).
            "monitoring-tick": {
                "task": MONITORING_TICK_TASK,
                "schedule": float(settings.schedule_tick_s),
            },
        },
    )
    return app


app = create_celery(get_settings())
