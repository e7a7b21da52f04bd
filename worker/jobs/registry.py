"""Job kinds by name."""

from worker.jobs.comparison import ComparisonJob
from worker.jobs.kind import JobKind
from worker.jobs.reconstruction import ReconstructionJob

JOB_KINDS: dict[str, JobKind] = {
    ComparisonJob.name: ComparisonJob(),
    ReconstructionJob.name: ReconstructionJob(),
}


def job_kind(name: str) -> JobKind:
    try:
        return JOB_KINDS[name]
    except KeyError:
        raise LookupError(f"unknown job kind {name!r}") from None
