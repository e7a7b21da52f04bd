"""The job layer's one interface for the services and the API: submit, retry, describe.

Background work of every kind (comparison, reconstruction, report, training) is submitted
the same way: `new_job` with the kind's stages and its owner row, commit, then `start_job`
queues the first stage. No caller names a Celery task or a job kind's class; the stage
runner (runner.py) does the rest: retries with backoff, heartbeats, stall recovery,
progress, the job's events.
"""

import logging

from celery import Celery
from sqlalchemy.orm import Session

from backend.db.models import Job, JobState, StageRun, StageState
from worker.dispatch import dispatch_stage
from worker.jobs.kind import JobKindName
from worker.jobs.registry import job_kind
from worker.training.trainer import MODEL_KINDS as TRAINABLE_MODEL_KINDS

log = logging.getLogger(__name__)
__all__ = [
    "TRAINABLE_MODEL_KINDS",
    "JobKindName",
    "QueueUnavailable",
    "job_progress",
    "kind_stages",
    "new_job",
    "reset_failed",
    "retry_job",
    "stage_help",
    "start_job",
]


def kind_stages(kind: JobKindName) -> tuple[str, ...]:
    """The stages a job of `kind` runs (a comparison's depend on its method: stages_for)."""
    return tuple(job_kind(kind).stages)


def stage_help(job: Job, stage: str) -> str:
    """What a stage of the job does, in one line, as its kind declares it."""
    try:
        return job_kind(job.kind).stage_help(stage)
    except LookupError:
        return ""


def retry_job(celery: Celery, session: Session, job: Job) -> None:
    """Run a failed job again from its failed stage (finished stages are not redone);
    QueueUnavailable when the broker cannot take it."""
    reset_failed(job)
    job_kind(job.kind).on_retry(session, job)
    session.commit()
    start_job(celery, session, job)


class QueueUnavailable(Exception):
    pass


def new_job(
    site_id: int | None, kind: JobKindName, stages: tuple[str, ...] | None = None, **owner: int
) -> Job:
    """A queued job of `kind` (site None: a job of no site, e.g. training) for the owner
    row named by one keyword: comparison_id, survey_id, report_id or training_run_id.
    `stages`: the kind's own unless given (a comparison's depend on its method)."""
    stages = kind_stages(kind) if stages is None else stages
    return Job(
        site_id=site_id,
        kind=kind,
        state=JobState.queued,
        stages=[
            StageRun(stage=stage, position=i, state=StageState.pending, progress=0.0, attempts=0)
            for i, stage in enumerate(stages)
        ],
        **owner,
    )


def start_job(celery: Celery, session: Session, job: Job, *, recover_later: bool = False) -> None:
    """Queue the job's first unfinished stage. The job must be committed already.

    If the broker cannot be reached the job fails (QueueUnavailable), unless
    `recover_later`: then it stays queued and the recovery sweep queues it (a stage never
    queued counts as stalled), for work nobody waits on at once (reports).
    """
    stage = next(r.stage for r in job.stages if r.state != StageState.succeeded)
    try:
        dispatch_stage(celery, session, job.id, stage)
        session.commit()
    except Exception as exc:
        session.rollback()
        if recover_later:
            log.warning("job %s not queued (%s); the recovery sweep will queue it", job.id, exc)
            return
        job.state = JobState.failed
        job.error = f"could not queue the job: {exc}"
        session.commit()
        raise QueueUnavailable(job.error) from exc
    session.refresh(job)


def job_progress(job: Job) -> float:
    if not job.stages:
        return 0.0
    done = sum(1.0 if r.state == StageState.succeeded else r.progress for r in job.stages)
    return round(done / len(job.stages), 4)


def reset_failed(job: Job) -> None:
    """Make a failed job runnable again from its failed stage; finished stages are kept."""
    for run in job.stages:
        if run.state in (StageState.failed, StageState.running, StageState.pending):
            run.state = StageState.pending
            run.progress = 0.0
            run.queued_at = None
    job.state = JobState.queued
    job.error = None
    job.finished_at = None
