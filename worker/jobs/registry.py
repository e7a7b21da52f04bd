"""Job kinds by name."""

from worker.jobs.comparison import ComparisonJob
from worker.jobs.context import JobContext
from worker.jobs.kind import JobKind
from worker.jobs.products import StorageJob
from worker.jobs.reconstruction import ReconstructionJob
from worker.jobs.report import ReportJob
from worker.jobs.training import TrainingJob

JOB_KINDS: dict[str, type[StorageJob]] = {
    ComparisonJob.name: ComparisonJob,
    ReconstructionJob.name: ReconstructionJob,
    ReportJob.name: ReportJob,
    TrainingJob.name: TrainingJob,
}


def job_kind(name: str, context: JobContext | None = None) -> JobKind:
    """The kind `name`; with the running process's `context` to run stages."""
    try:
        return JOB_KINDS[name](context)
    except KeyError:
        raise LookupError(f"unknown job kind {name!r}") from None
