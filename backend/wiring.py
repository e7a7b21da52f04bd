"""What every process of the platform sets up once, from its settings.

Called by each composition root (the API app factory and the Celery worker): the detection
methods kept outside the project are registered, and the services that react to jobs
subscribe to the job layer's events (the job layer never imports the services).
"""

from backend.config import Settings
from backend.services import alerts, tile_prerender_queue
from worker.jobs.events import JobEvent, subscribe
from worker.pipeline.detection_methods import load_method_modules


def wire(settings: Settings) -> None:
    """Idempotent: a second call registers and subscribes nothing new."""
    load_method_modules(settings.detection_method_modules)
    subscribe(JobEvent.comparison_succeeded, alerts.comparison_succeeded)
    subscribe(JobEvent.job_failed, alerts.job_failed)
    subscribe(JobEvent.report_ready, alerts.report_ready)
    subscribe(JobEvent.comparison_succeeded, tile_prerender_queue.comparison_succeeded)
    subscribe(JobEvent.survey_ready, tile_prerender_queue.survey_ready)
