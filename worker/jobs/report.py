"""The report job: one stage, "build", that renders a report's PDF and HTML.

`load_inputs` gathers what the report shows from the database (backend/db/reports.py:
gather) as plain values; `run_stage` renders them with the report library
(worker/reports: map figure, PDF, HTML) into `reports/{site}/{report}/`, no database;
`store_stage_result` records the files and totals on the report. The hooks keep the
report's own status, as the comparison job does for its comparison; a finished report is
published as `report_ready` (the alerts subscribe to it, backend/wiring.py).

A report that cannot be made (its comparison is gone or unfinished) fails at once with
the reason, through an InputError raised by the stage, and is not retried; any other
error (a file that cannot be written, ...) is retried with backoff like every stage.
"""

from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from backend.db import reports
from backend.db.models import Job, JobState, Report
from backend.storage_layout import report_folder
from worker.jobs.events import JobEvent, publish
from worker.jobs.kind import JobKindName
from worker.jobs.products import StorageJob
from worker.pipeline.errors import InputError
from worker.pipeline.progress import ProgressFn
from worker.reports import Change, DetectionRow, ReportData


def data_to_json(data: ReportData) -> dict[str, Any]:
    """The report's data as JSON-friendly values (the job kinds' inputs are plain data)."""
    values = asdict(data)
    values["created_at"] = data.created_at.isoformat()
    values["dh_path"], values["dsm_path"] = str(data.dh_path), str(data.dsm_path)
    if data.change is not None and data.change.previous_created_at is not None:
        values["change"]["previous_created_at"] = data.change.previous_created_at.isoformat()
    return values


def data_from_json(values: dict[str, Any]) -> ReportData:
    change = dict(values["change"]) if values["change"] is not None else None
    if change is not None and change["previous_created_at"] is not None:
        change["previous_created_at"] = datetime.fromisoformat(change["previous_created_at"])
    return ReportData(
        **{
            **values,
            "created_at": datetime.fromisoformat(values["created_at"]),
            "dh_path": Path(values["dh_path"]),
            "dsm_path": Path(values["dsm_path"]),
            "detections": [DetectionRow(**row) for row in values["detections"]],
            "change": Change(**change) if change is not None else None,
        }
    )


class ReportJob(StorageJob):
    name = JobKindName.report
    stages: tuple[str, ...] = ("build",)

    def stage_help(self, stage: str) -> str:
        return "Draw the site map and write the report's PDF and HTML"

    def _report(self, session: Session, job: Job) -> Report:
        return self.owner(session, Report, job.report_id, job.id)

    def load_inputs(self, session: Session, job: Job) -> dict[str, Any]:
        report = self._report(session, job)
        folder = str(self.storage.absolute(report_folder(report.site_id, report.id)))
        try:
            data = reports.gather(session, self.storage, report)
        except reports.ReportRejected as exc:
            # Raised by the stage (as an InputError), so that the job fails at once.
            return {"rejected": str(exc), "out_dir": folder}
        return {"data": data_to_json(data), "out_dir": folder}

    def run_stage(self, stage: str, inputs: dict[str, Any], progress: ProgressFn) -> dict[str, Any]:
        if inputs.get("rejected"):
            raise InputError(inputs["rejected"])
        data = data_from_json(inputs["data"])
        # The renderer is imported by the report's stage only (reportlab and matplotlib: most
        # of a second in every worker's start otherwise).
        from worker.reports.render import build_report

        build_report(data, Path(inputs["out_dir"]))
        return {
            "comparison_id": data.comparison_id,
            "totals": data.totals,
            "language": data.language,
        }

    def store_stage_result(
        self, session: Session, job: Job, stage: str, result: dict[str, Any]
    ) -> None:
        report = self._report(session, job)
        reports.store_files(
            session,
            self.storage,
            report,
            result["comparison_id"],
            result["totals"],
            result.get("language", "en"),  # a stage stored before reports had languages
        )

    def on_success(self, session: Session, job: Job) -> None:
        report = self._report(session, job)
        report.status, report.error, report.finished_at = JobState.succeeded, None, _now()
        session.flush()
        publish(JobEvent.report_ready, self.context.settings, session, report)

    def on_failure(self, session: Session, job: Job, reason: str) -> None:
        report = session.get(Report, job.report_id)
        if report is not None:
            report.status, report.error, report.finished_at = JobState.failed, reason, _now()

    def on_retry(self, session: Session, job: Job) -> None:
        report = self._report(session, job)
        report.status, report.error, report.finished_at = JobState.queued, None, None


def _now() -> datetime:
    return datetime.now(UTC)
