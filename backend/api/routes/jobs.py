from fastapi import APIRouter, HTTPException, status
from sqlalchemy import select

from backend.api.access import SiteAnalyst, SiteViewer
from backend.api.deps import CeleryDep, SessionDep, owned_by_site
from backend.api.schemas import JobOut
from backend.api.serializers import job_out
from backend.db.models import Job, JobState, Site
from backend.ids import RowId
from worker.jobs import control

router = APIRouter(prefix="/sites/{site_id}/jobs", tags=["jobs"])


def job_of_site(session: SessionDep, site: Site, job_id: RowId) -> Job:
    return owned_by_site(session, Job, site, job_id, "job")


@router.get("", response_model=list[JobOut])
def list_jobs(site: SiteViewer, session: SessionDep) -> list[JobOut]:
    jobs = session.scalars(select(Job).where(Job.site_id == site.id).order_by(Job.id.desc()))
    return [job_out(job) for job in jobs]


@router.get("/{job_id}", response_model=JobOut, summary="Job state with per-stage progress")
def get_job(job_id: RowId, site: SiteViewer, session: SessionDep) -> JobOut:
    return job_out(job_of_site(session, site, job_id))


@router.post("/{job_id}/retry", response_model=JobOut, status_code=status.HTTP_202_ACCEPTED)
def retry_job(job_id: RowId, site: SiteAnalyst, session: SessionDep, celery: CeleryDep) -> JobOut:
    """Run a failed job again from its failed stage; finished stages are not redone."""
    job = job_of_site(session, site, job_id)
    if job.state != JobState.failed:
        raise HTTPException(status.HTTP_409_CONFLICT, f"job {job.id} is {job.state}, not failed")
    try:
        control.retry_job(celery, session, job)
    except control.QueueUnavailable as exc:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, str(exc)) from None
    return job_out(job)
