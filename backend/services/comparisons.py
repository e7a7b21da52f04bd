"""Create a comparison of two surveys of one site and queue its job."""

from celery import Celery
from shapely.geometry import shape
from sqlalchemy.orm import Session

from backend.db.models import Comparison, Job, JobState, Site, Survey, SurveyStatus
from backend.services import models
from backend.services.jobs import QueueUnavailable, new_job, start_job
from worker.jobs.comparison import ComparisonJob
from worker.pipeline.comparison import METHODS, ComparisonOptions, stages_for
from worker.pipeline.errors import InputError


class ComparisonRejected(ValueError):
    """The request cannot make a valid comparison; the message says why."""


def default_method(session: Session) -> str:
    """ "cnn" when a detection model is installed (registered or shipped), else "threshold"."""
    return "cnn" if models.default_model(session) is not None else "threshold"


def _model_reference(session: Session, requested: str | None) -> str:
    """The "name@version" a cnn comparison will run: the one requested (a registered
    model, never a path) or the default; kept in the comparison's parameters."""
    if requested in (None, "", "default"):
        row = models.default_model(session)
        if row is None:
            raise ComparisonRejected("no detection model is installed: use method threshold")
        return models.reference(row)
    try:
        return models.reference(models.find_model(session, requested))
    except models.UnknownModel as exc:
        raise ComparisonRejected(str(exc)) from None


def _survey_of_site(session: Session, site: Site, survey_id: int, role: str) -> Survey:
    survey = session.get(Survey, survey_id)
    if survey is None:
        raise ComparisonRejected(f"{role} survey {survey_id} does not exist")
    if survey.site_id != site.id:
        raise ComparisonRejected(
            f"{role} survey {survey_id} belongs to another site; "
            "a comparison needs two surveys of the same site"
        )
    if survey.status != SurveyStatus.ready or not any(p.kind == "dsm" for p in survey.products):
        raise ComparisonRejected(f"{role} survey {survey_id} has no DSM ready yet")
    return survey


def create_comparison(
    celery: Celery,
    session: Session,
    site: Site,
    pre_survey_id: int,
    post_survey_id: int,
    method: str | None,
    parameters: dict,
) -> tuple[Comparison, Job]:
    method = method or default_method(session)
    if method not in METHODS:
        raise ComparisonRejected(f"unknown method {method!r}; choose one of: {', '.join(METHODS)}")
    if pre_survey_id == post_survey_id:
        raise ComparisonRejected("pre and post survey are the same survey")
    pre = _survey_of_site(session, site, pre_survey_id, "pre")
    post = _survey_of_site(session, site, post_survey_id, "post")
    if pre.footprint and post.footprint:
        overlap = shape(pre.footprint).intersection(shape(post.footprint)).area
        if overlap <= 0:
            raise ComparisonRejected(f"the DSMs of surveys {pre.id} and {post.id} do not overlap")
    try:
        options = ComparisonOptions.from_dict({**parameters, "method": method})
    except (InputError, TypeError, ValueError) as exc:
        raise ComparisonRejected(f"invalid parameters: {exc}") from exc
    if method == "cnn":
        options.cnn.model = _model_reference(session, options.cnn.model)

    comparison = Comparison(
        site_id=site.id,
        pre_survey_id=pre.id,
        post_survey_id=post.id,
        method=method,
        parameters=options.to_dict(),
        status=JobState.queued,
    )
    session.add(comparison)
    session.flush()
    job = new_job(site.id, ComparisonJob.name, stages_for(method), comparison_id=comparison.id)
    session.add(job)
    session.commit()
    try:
        start_job(celery, session, job)
    except QueueUnavailable as exc:
        comparison.status = JobState.failed
        comparison.error = str(exc)
        session.commit()
        raise
    return comparison, job
