"""Turn database rows into response bodies where a plain from_attributes is not enough."""

from typing import Any

from backend.api.schemas import (
    ComparisonOut,
    DetectionOut,
    JobOut,
    ProductOut,
    QualityOut,
    StageRunOut,
    StoredFileOut,
    SurveyOut,
)
from backend.db import detections
from backend.db.models import Comparison, Detection, Job, Product, Survey
from backend.services.comparisons import comparison_warnings, detection_info
from backend.services.feedback import feedback_summary
from backend.services.survey_sources import report_quality, survey_report, survey_warnings
from backend.storage import LocalStorage
from backend.urls import api_url
from worker.jobs.control import job_progress, stage_help


def product_out(product: Product) -> ProductOut:
    return ProductOut(
        id=product.id,
        kind=product.kind,
        survey_id=product.survey_id,
        comparison_id=product.comparison_id,
        crs=product.crs,
        file=StoredFileOut.model_validate(product.file),
        download_url=api_url("sites", product.site_id, "products", product.id, "file"),
        created_at=product.created_at,
    )


def survey_out(survey: Survey, storage: LocalStorage) -> SurveyOut:
    out = SurveyOut.model_validate(survey)
    report = survey_report(storage, survey)  # read once for both
    out.warnings = survey_warnings(survey, report)
    quality = report_quality(report)
    out.quality = None if quality is None else QualityOut.model_validate(quality)
    return out


def job_out(job: Job) -> JobOut:
    return JobOut(
        id=job.id,
        site_id=job.site_id,
        kind=job.kind,
        comparison_id=job.comparison_id,
        survey_id=job.survey_id,
        state=job.state,
        progress=job_progress(job),
        error=job.error,
        created_at=job.created_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
        stages=[
            StageRunOut.model_validate(run).model_copy(update={"help": stage_help(job, run.stage)})
            for run in job.stages
        ],
    )


def comparison_out(comparison: Comparison, job: Job | None, storage: LocalStorage) -> ComparisonOut:
    out = ComparisonOut.model_validate(comparison)
    out.job_id = job.id if job else None
    out.detection = DetectionOut(**detection_info(comparison, job))
    out.warnings = comparison_warnings(storage, comparison)
    return out


def detection_feature(detection: Detection, label: int | None = None) -> dict[str, Any]:
    """The stored record (as in the product file), its label and what people said about it."""
    return detections.detection_feature(
        detection, {"feedback": feedback_summary(detection)}, label=label
    )
