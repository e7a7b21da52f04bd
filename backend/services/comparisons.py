"""Create a comparison of two surveys of one site and queue its job; say how it detects."""

from collections.abc import Mapping
from typing import Any

from celery import Celery
from shapely.geometry import shape
from sqlalchemy.orm import Session

from backend.db.models import Comparison, Job, JobState, Site, Survey, SurveyStatus
from backend.services import models
from backend.services.jobs import QueueUnavailable, new_job, start_job
from worker.jobs.comparison import ComparisonJob
from worker.pipeline.comparison import (
    METHOD_SUMMARIES,
    METHODS,
    STAGES_BY_METHOD,
    ComparisonOptions,
    default_method,
    stages_for,
)
from worker.pipeline.errors import InputError
from worker.pipeline.scorer import shipped_scorer_available


class ComparisonRejected(ValueError):
    """The request cannot make a valid comparison; the message says why."""


def list_methods() -> list[dict[str, Any]]:
    """The detection methods as the library defines them, its default marked.

    The library's `default_method()` is the one default of the product (CLI, API, page),
    so that a comparison made from the page and one made over the API without a method
    run the same way.
    """
    default = default_method()
    return [
        {
            "name": name,
            "summary": METHOD_SUMMARIES[name],
            "stages": list(STAGES_BY_METHOD[name]),
            "default": name == default,
        }
        for name in METHODS
    ]


def stage_results(comparison: Comparison, job: Job | None) -> dict[str, dict[str, Any]]:
    """Results of the comparison's stages so far.

    A succeeded comparison keeps them in its summary (no need to load the job's stages,
    which a list of comparisons would do once per row); before that, the latest job's
    stages have them as each finishes (the LoD before the detections).
    """
    kept = (comparison.summary or {}).get("stages")
    if comparison.status == JobState.succeeded and kept:
        return dict(kept)
    if job is not None:
        return {run.stage: run.result for run in job.stages if run.result}
    return dict(kept or {})


def detection_model(comparison: Comparison, results: Mapping[str, Mapping[str, Any]]) -> str | None:
    """ "name@version" of the model that found (or will find) the detections, if any.

    scored: the scorer the score stage ran (known once it has run); cnn: the registered
    model kept in the parameters at creation; threshold: none.
    """
    if comparison.method == "scored":
        return (results.get("score") or {}).get("model")
    if comparison.method == "cnn":
        ran = (results.get("detect") or {}).get("model")
        return ran or ((comparison.parameters or {}).get("cnn") or {}).get("model")
    return None


def detection_info(comparison: Comparison, job: Job | None) -> dict[str, Any]:
    """How the comparison detects: method, the LoD the difference stage applied (median
    of the per-pixel LoD95, its 10th-90th percentiles, the error model) and the model.
    LoD fields are None until the difference stage has run."""
    results = stage_results(comparison, job)
    difference = results.get("difference") or {}
    return {
        "method": comparison.method,
        "lod_m": difference.get("lod_m"),
        "lod_p10_m": difference.get("lod_p10_m"),
        "lod_p90_m": difference.get("lod_p90_m"),
        "error_model": difference.get("error_model"),
        "model": detection_model(comparison, results),
    }


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


def _check_scorer(options: ComparisonOptions) -> None:
    """A scored comparison runs the scorer that ships with the installation, nothing else.

    A scorer path from an API user would be a file on the server opened by the worker;
    as with detection models, only what the installation provides runs.
    """
    if options.score.scorer is not None:
        raise ComparisonRejected(
            "the scored method runs the scorer shipped with slidewatch; "
            "parameters.score.scorer cannot be set over the API"
        )
    if not shipped_scorer_available():
        raise ComparisonRejected(
            "the scorer of the scored method is not installed: use method threshold"
        )


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
    method = method or default_method()
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
    if method == "scored":
        _check_scorer(options)

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
