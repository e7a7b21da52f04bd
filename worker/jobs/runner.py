"""Run one stage of a job, exactly the way every worker does it.

A stage is *claimed* with one conditional UPDATE (pending, or running with a stale
heartbeat), so that two workers never run it at once, and a stage whose worker died can
be taken over. While it runs, a thread keeps its heartbeat fresh. Finished stages are
never run again; a redelivered message for one only makes sure the next stage is queued.

A claim is fenced by its attempt number (the `attempts` the claim set): the heartbeat and
the stored result are written only while the stage is still running under that attempt.
A worker that was taken for dead (its heartbeat stopped for `stale_stage_after_s`) but
was only stalled can therefore not overwrite the result of the attempt that took over,
nor keep the stage looking alive: a live stage's result is stored once. Before a claimed
stage runs, the temporaries a killed attempt left in the job's folder are removed
(worker/jobs/leftovers.py).
"""

import logging
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session

from backend.db.models import Job, JobState, StageRun, StageState
from worker.jobs.context import JobContext
from worker.jobs.events import JobEvent, publish
from worker.jobs.leftovers import job_folder, remove_leftovers
from worker.jobs.registry import job_kind

log = logging.getLogger(__name__)


def utcnow() -> datetime:
    return datetime.now(UTC)


# A stage's log (StageRun.log): at most this many lines, each cut to this many characters,
# so that a chatty library cannot grow a row without bound.
LOG_LINES = 200
LOG_LINE_CHARS = 500
CAPTURED_LOGGERS = ("worker", "backend")


def log_line(level: str, message: str) -> str:
    return f"{utcnow():%H:%M:%S} {level} {message}"[:LOG_LINE_CHARS]


def _append_log(run: StageRun, lines: list[str]) -> None:
    # A new list: the JSON column is saved when it is assigned, not when mutated.
    run.log = [*(run.log or []), *lines][-LOG_LINES:]


class _StageLog(logging.Handler):
    """What the stage's code logs from this thread while it runs (as far as the process's
    logging levels let through: the library's warnings at least), for the stage's log."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[str] = []
        self._thread = threading.get_ident()
        self._loggers = [logging.getLogger(name) for name in CAPTURED_LOGGERS]

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self._thread and len(self.lines) < LOG_LINES:
            self.lines.append(log_line(record.levelname, record.getMessage()))

    def __enter__(self) -> "_StageLog":
        for logger in self._loggers:
            logger.addHandler(self)
        return self

    def __exit__(self, *exc: object) -> None:
        for logger in self._loggers:
            logger.removeHandler(self)


def _keep_log(context: JobContext, run_id: int, lines: list[str]) -> None:
    if not lines:
        return
    with context.session_scope() as session:
        run = session.get(StageRun, run_id)
        if run is not None:
            _append_log(run, lines)


def _stage_run(session: Session, job_id: int, stage: str) -> StageRun | None:
    return session.scalar(
        select(StageRun).where(StageRun.job_id == job_id, StageRun.stage == stage)
    )


def _following(job: Job, run: StageRun) -> StageRun | None:
    later = [r for r in job.stages if r.position > run.position]
    return min(later, key=lambda r: r.position) if later else None


def _claim(session: Session, run_id: int, now: datetime, stale_after_s: float) -> int | None:
    """Take the stage if it is pending or its worker is dead: the attempt number that
    fences this claim, None if a live worker has it."""
    stale = now - timedelta(seconds=stale_after_s)
    claimed = session.execute(
        update(StageRun)
        .where(
            StageRun.id == run_id,
            or_(
                StageRun.state == StageState.pending,
                (StageRun.state == StageState.running) & (StageRun.heartbeat_at < stale),
            ),
        )
        .values(
            state=StageState.running,
            attempts=StageRun.attempts + 1,
            started_at=now,
            heartbeat_at=now,
            progress=0.0,
            error=None,
        )
        .execution_options(synchronize_session=False)
    )
    if claimed.rowcount != 1:
        return None
    # The row is locked by the UPDATE until this transaction ends (PostgreSQL's row lock,
    # SQLite's database lock): the number read is the one this claim wrote.
    return session.scalar(select(StageRun.attempts).where(StageRun.id == run_id))


def _ours(run_id: int, attempt: int) -> Any:
    """The stage is still running under this claim (no other worker took it over)."""
    return (
        (StageRun.id == run_id)
        & (StageRun.state == StageState.running)
        & (StageRun.attempts == attempt)
    )


class _Heartbeat:
    """Keeps a running stage's heartbeat fresh and writes its progress, from a thread."""

    def __init__(self, context: JobContext, run_id: int, attempt: int) -> None:
        self.context = context
        self.run_id = run_id
        self.attempt = attempt
        self.interval_s = context.settings.heartbeat_interval_s
        self.progress = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)

    def __enter__(self) -> "_Heartbeat":
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def report(self, fraction: float) -> None:
        self.progress = min(max(float(fraction), 0.0), 1.0)

    def _beat(self) -> None:
        while not self._stop.wait(self.interval_s):
            try:
                with self.context.session_scope() as session:
                    beat = session.execute(
                        update(StageRun)
                        .where(_ours(self.run_id, self.attempt))
                        .values(heartbeat_at=utcnow(), progress=self.progress)
                    )
                if beat.rowcount == 0:
                    log.warning(
                        "stage run %s: attempt %s was taken over; its result will be dropped",
                        self.run_id,
                        self.attempt,
                    )
                    return
            except Exception:  # a missed beat is harmless; the next one retries
                log.warning("heartbeat of stage run %s failed", self.run_id, exc_info=True)


def execute_stage(
    context: JobContext,
    job_id: int,
    stage: str,
    on_claim: Callable[[int], None] | None = None,
) -> str | None:
    """Run `stage` of job `job_id` if it is not done; return the stage to queue next.

    Raises what the stage raised for transient failures (the caller retries, passing the
    attempt that `on_claim` was given to `record_retry` or `fail_job`); input errors fail
    the job at once with the error's message as the reason.
    """
    from worker.pipeline.errors import InputError

    with context.session_scope() as session:
        run = _stage_run(session, job_id, stage)
        if run is None:
            return None
        job = run.job
        if job.state in (JobState.succeeded, JobState.failed):
            return None
        if run.state == StageState.succeeded:
            following = _following(job, run)
            if following and following.state == StageState.pending and following.queued_at is None:
                return following.stage
            return None
        now = utcnow()
        attempt = _claim(session, run.id, now, context.settings.stale_stage_after_s)
        if attempt is None:
            return None  # a live worker has it
        if on_claim is not None:
            on_claim(attempt)
        if job.state == JobState.queued:
            job.state = JobState.running
            job.started_at = now
        kind = job_kind(job.kind, context)
        _append_log(run, [log_line("INFO", f"attempt {run.attempts + 1} started")])
        inputs: dict[str, Any] = kind.load_inputs(session, job)
        run_id = run.id
    remove_leftovers(job_folder(inputs))

    started = time.perf_counter()
    captured = _StageLog()
    try:
        with captured, _Heartbeat(context, run_id, attempt) as heartbeat:
            result = kind.run_stage(stage, inputs, heartbeat.report)
    except InputError as exc:
        _keep_log(context, run_id, captured.lines)
        fail_job(context, job_id, stage, str(exc), attempt)
        return None
    except Exception as exc:
        # The caller retries or fails the stage; what it logged is kept either way.
        _keep_log(context, run_id, [*captured.lines, log_line("ERROR", f"{exc!r}")])
        raise
    result = {**result, "wall_seconds": round(time.perf_counter() - started, 3)}

    with context.session_scope() as session:
        # Fenced: the conditional UPDATE locks the row for the rest of the transaction, or
        # finds that another attempt has the stage now, whose result is the one kept.
        if (
            session.execute(
                update(StageRun).where(_ours(run_id, attempt)).values(heartbeat_at=utcnow())
            ).rowcount
            == 0
        ):
            log.warning(
                "stage %s of job %s: attempt %s was taken over; its result is dropped",
                stage,
                job_id,
                attempt,
            )
            return None
        run = session.get(StageRun, run_id)
        job = run.job
        kind.store_stage_result(session, job, stage, result)
        run.state = StageState.succeeded
        run.progress = 1.0
        run.finished_at = utcnow()
        run.result = result
        run.error = None
        done = log_line("INFO", f"succeeded in {result['wall_seconds']:.1f} s")
        _append_log(run, [*captured.lines, done])
        following = _following(job, run)
        if following is None:
            job.state = JobState.succeeded
            job.finished_at = utcnow()
            job.error = None
            session.flush()
            kind.on_success(session, job)
            return None
        return following.stage


def _taken_over(run: StageRun, attempt: int | None) -> bool:
    """A failure of `attempt` that must not touch the stage: another attempt has it now."""
    if attempt is None or (run.state == StageState.running and run.attempts == attempt):
        return False
    log.warning(
        "stage %s of job %s: attempt %s failed after it was taken over; ignored",
        run.stage,
        run.job_id,
        attempt,
    )
    return True


def record_retry(
    context: JobContext,
    job_id: int,
    stage: str,
    error: str,
    delay_s: float,
    attempt: int | None = None,
) -> bool:
    """A transient failure: the stage goes back to pending until its retry is delivered.

    False, and nothing recorded, when `attempt` (the failed one's claim) was taken over:
    the attempt running now is not to be retried."""
    with context.session_scope() as session:
        run = _stage_run(session, job_id, stage)
        if run is None or _taken_over(run, attempt):
            return False
        if run.state != StageState.succeeded:
            run.state = StageState.pending
            run.error = f"attempt {run.attempts} failed, retrying in {delay_s:.0f} s: {error}"
            run.queued_at = utcnow() + timedelta(seconds=delay_s)
            _append_log(run, [log_line("WARNING", run.error)])
        return True


def fail_job(
    context: JobContext, job_id: int, stage: str, reason: str, attempt: int | None = None
) -> None:
    """The job fails at `stage` (unless `attempt`, the failed one's claim, was taken over:
    the attempt running now may yet succeed)."""
    with context.session_scope() as session:
        run = _stage_run(session, job_id, stage)
        if run is None or _taken_over(run, attempt):
            return
        job = run.job
        run.state = StageState.failed
        run.error = reason
        run.finished_at = utcnow()
        _append_log(run, [log_line("ERROR", f"failed: {reason}")])
        job.state = JobState.failed
        job.error = f"{stage}: {reason}"
        job.finished_at = utcnow()
        job_kind(job.kind, context).on_failure(session, job, job.error)
        session.flush()
        if job.site_id is not None:  # its listeners alert a site; training belongs to none
            publish(JobEvent.job_failed, context.settings, session, job)
