"""Create jobs with their stages, queue them, and describe their progress."""

from celery import Celery
from sqlalchemy.orm import Session

from backend.db.models import Job, JobState, StageRun, StageState
from worker.dispatch import dispatch_stage


class QueueUnavailable(Exception):
    pass


def new_job(site_id: int, kind: str, stages: tuple[str, ...], **owner: int) -> Job:
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


def start_job(celery: Celery, session: Session, job: Job) -> None:
    """Queue the job's first unfinished stage. The job must be committed already."""
    stage = next(r.stage for r in job.stages if r.state != StageState.succeeded)
    try:
        dispatch_stage(celery, session, job.id, stage)
        session.commit()
    except Exception as exc:
        session.rollback()
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
