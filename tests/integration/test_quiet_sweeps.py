"""The recovery sweep runs every few seconds: its routine lines stay out of the log people
read, what it finds and every other task's lines stay in."""

import logging

import pytest

from worker.celery_app import RECOVER_TASK, RUN_STAGE_TASK


def test_the_sweeps_routine_lines_are_left_out(caplog: pytest.LogCaptureFixture) -> None:
    trace, beat = logging.getLogger("celery.app.trace"), logging.getLogger("celery.beat")
    with caplog.at_level(logging.INFO):
        line = "Task %(name)s[%(id)s] succeeded in %(runtime)ss: %(return_value)s"
        trace.info(line, {"name": RECOVER_TASK, "id": "a", "runtime": 0.001, "return_value": 0})
        beat.info("Scheduler: Sending due task recover-stalled-jobs (%s)", RECOVER_TASK)
        trace.info(line, {"name": RUN_STAGE_TASK, "id": "b", "runtime": 3.2, "return_value": {}})
        trace.warning("Task %s[%s] raised unexpected: boom", RECOVER_TASK, "c")
    assert [r.getMessage() for r in caplog.records] == [
        f"Task {RUN_STAGE_TASK}[b] succeeded in 3.2s: {{}}",
        f"Task {RECOVER_TASK}[c] raised unexpected: boom",
    ]
