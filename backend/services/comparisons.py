"""Create a comparison of two surveys of one site and queue its job; say how it detects
and what to bear in mind reading it (a survey that missed its quality bounds)."""

import json
from typing import Any

from celery import Celery
from shapely.geometry import shape
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db import model_registry
from backend.db.detections import detection_model
from backend.db.models import Comparison, Job, JobState, Site, Survey, SurveyStatus
from backend.services.survey_sources import report_quality, survey_report
from backend.storage import LocalStorage
from worker.jobs.control import JobKindName, QueueUnavailable, new_job, start_job
from worker.pipeline.comparison import ComparisonOptions, stages_for
from worker.pipeline.detection_methods import default_method, detection_method, detection_methods
from worker.pipeline.errors import InputError
from worker.pipeline.quality import failed_messages


class ComparisonRejected(ValueError):
    """The request cannot make a valid comparison; the message says why."""


class AlreadyCompared(Exception):
    """The same comparison exists (same surveys, method and parameters, not failed): it is
    opened rather than made again, unless asked to run again."""

    def __init__(self, comparison: Comparison) -> None:
        super().__init__(f"comparison {comparison.id} already compares these surveys this way")
        self.comparison = comparison


def _same_comparison(
    session: Session, site: Site, pre: Survey, post: Survey, method: str, parameters: dict
) -> Comparison | None:
    candidates = session.scalars(
        select(Comparison)
        .where(
            Comparison.site_id == site.id,
            Comparison.pre_survey_id == pre.id,
            Comparison.post_survey_id == post.id,
            Comparison.method == method,
            Comparison.status != JobState.failed,
        )
        .order_by(Comparison.id.desc())
    )
    # Parameters compared as stored (normalised by ComparisonOptions, then as JSON keeps
    # them: tuples become lists), not in SQL: JSON equality differs between databases.
    wanted = json.loads(json.dumps(parameters))
    return next((c for c in candidates if c.parameters == wanted), None)


def list_methods() -> list[dict[str, Any]]:
    """The detection methods as the library defines them, its default marked.

    The library's `default_method()` is the one default of the product (CLI, API, page),
    so that a comparison made from the page and one made over the API without a method
    run the same way.
    """
    default = default_method()
    return [
        {
            "name": method.name,
            "summary": method.summary,
            "stages": list(stages_for(method.name)),
            "default": method.name == default,
        }
        for method in detection_methods()
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


def comparison_warnings(storage: LocalStorage, comparison: Comparison) -> list[str]:
    """Each quality check the comparison's pre- or post-event survey failed, naming the
    survey: a change found between them is no surer than the surveys (none for surveys
    without a reconstruction report, such as uploaded DSMs)."""
    warnings = []
    for role, survey in (
        ("pre-event", comparison.pre_survey),
        ("post-event", comparison.post_survey),
    ):
        quality = report_quality(survey_report(storage, survey))
        if quality is not None:
            warnings += [
                f'The {role} survey "{survey.name}" missed its quality bounds: {message}'
                for message in failed_messages(quality)
            ]
    return warnings


def _model_reference(session: Session, requested: str | None) -> str:
    """The "name@version" a comparison's model will be: the one requested (a registered
    model, never a path) or the default; kept in the comparison's parameters."""
    if requested in (None, "", "default"):
        row = model_registry.default_model(session)
        if row is None:
            raise ComparisonRejected("no detection model is installed: use method threshold")
        return model_registry.reference(row)
    try:
        return model_registry.reference(model_registry.find_model(session, requested))
    except model_registry.UnknownModel as exc:
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
    *,
    name: str = "",
    reuse: bool = False,
) -> tuple[Comparison, Job]:
    """Queue a comparison of two ready surveys; with `reuse`, AlreadyCompared names the
    same comparison made before instead (a failed one is made again)."""
    try:
        chosen = detection_method(method or default_method())
    except InputError as exc:
        raise ComparisonRejected(str(exc)) from None
    method = chosen.name
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
        if chosen.check_request is not None:
            chosen.check_request(options.detection)
    except (InputError, TypeError, ValueError) as exc:
        raise ComparisonRejected(f"invalid parameters: {exc}") from exc
    if chosen.needs_model:
        options.detection.model = _model_reference(session, options.detection.model)
    if reuse:
        same = _same_comparison(session, site, pre, post, method, options.to_dict())
        if same is not None:
            raise AlreadyCompared(same)

    comparison = Comparison(
        site_id=site.id,
        pre_survey_id=pre.id,
        post_survey_id=post.id,
        name=name.strip(),
        method=method,
        parameters=options.to_dict(),
        status=JobState.queued,
    )
    session.add(comparison)
    session.flush()
    job = new_job(site.id, JobKindName.comparison, stages_for(method), comparison_id=comparison.id)
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
