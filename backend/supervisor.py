"""Run a few long-lived processes together: restart one that dies, stop them all together.

`slidewatch run` (API, worker, beat) and `slidewatch worker` (one Celery worker process
per unit of concurrency) are such supervisors. Why a supervisor of our own rather than
the process managers of Celery and uvicorn alone:

- A worker process that dies (killed by the kernel for memory, by an operator, by a crash
  in native code) must be back within seconds, so that its stage runs again soon
  (worker/jobs/recovery.py); Celery's own pool cannot be trusted to do it: a pool child
  killed while idle leaves the task-queue lock it waited in held, and the worker takes
  messages that no child ever runs (celery/billiard#104). So the workers run Celery's
  `solo` pool, one process each, and this supervisor replaces whichever exits.
- Stopping must stop everything, whatever the children are doing: a busy request keeps
  uvicorn's graceful shutdown waiting, a running stage keeps a Celery worker's warm
  shutdown waiting. Each child is asked (SIGTERM), then after `grace_s` killed (SIGKILL)
  with its whole process group, so that nothing it started is left behind.
- If the supervisor itself is killed, each child is killed by the kernel
  (PR_SET_PDEATHSIG on Linux) rather than left running without it.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

PR_SET_PDEATHSIG = 1
# A child that keeps dying sooner than this after it started is restarted after a growing
# delay (0, 1, 2, 4 ... at most MAX_RESTART_DELAY_S seconds), so that one that cannot start
# (a port in use, a database that is down) does not spin; one that ran longer, or died
# quickly only once, comes back at once.
QUICK_EXIT_S = 10.0
MAX_RESTART_DELAY_S = 30.0
POLL_S = 0.2


def _die_with_parent(parent: int) -> Callable[[], None]:
    """The child's first act after fork: be SIGKILLed when the supervisor dies."""

    def prepare() -> None:
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        except (OSError, AttributeError):  # not Linux: stopping cleanly is all we have
            return
        if os.getppid() != parent:  # the supervisor died before prctl took effect
            os._exit(1)

    return prepare


@dataclass
class Program:
    """One supervised command; `restart`: run it again whenever it exits."""

    name: str
    command: Sequence[str]
    restart: bool = True
    env: dict[str, str] | None = None
    process: subprocess.Popen | None = field(default=None, repr=False)
    started_at: float = 0.0
    quick_exits: int = 0
    restart_at: float | None = None
    exited: bool = False


class Supervisor:
    """Starts the programs, restarts those that exit (if they are to be), stops them all."""

    def __init__(
        self,
        programs: Sequence[Program],
        grace_s: float,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.programs = list(programs)
        self.grace_s = grace_s
        self.say = say or (lambda line: print(line, file=sys.stderr, flush=True))
        self._stopping = False

    def _start(self, program: Program) -> None:
        program.process = subprocess.Popen(
            list(program.command),
            env=program.env,
            # Its own process group: stopping kills what it started too (uvicorn's worker
            # processes), and a terminal's Ctrl-C reaches only the supervisor, which stops
            # the children: asked first, killed after the grace period.
            process_group=0,
            preexec_fn=_die_with_parent(os.getpid()),
        )
        program.started_at = time.monotonic()
        program.restart_at = None
        program.exited = False

    def run(self) -> int:
        """Start every program and watch them until SIGTERM or SIGINT; then stop them all."""
        previous = {
            sig: signal.signal(sig, self._request_stop) for sig in (signal.SIGTERM, signal.SIGINT)
        }
        try:
            for program in self.programs:
                self._start(program)
            while not self._stopping:
                self._watch()
                time.sleep(POLL_S)
        finally:
            self.stop()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        return 0

    def _request_stop(self, *_args: object) -> None:
        self._stopping = True

    def _watch(self) -> None:
        now = time.monotonic()
        for program in self.programs:
            process = program.process
            if process is None or process.poll() is None:
                continue  # running
            if program.restart_at is not None:
                if now >= program.restart_at:
                    self.say(f"supervisor: starting {program.name} again")
                    self._start(program)
                continue
            if not program.exited:
                # What the exited child started (e.g. uvicorn's workers) goes with it.
                _signal_group(process, signal.SIGKILL)
                program.exited = True
                lived = now - program.started_at
                program.quick_exits = program.quick_exits + 1 if lived < QUICK_EXIT_S else 0
                if not program.restart:
                    continue
                # At once after a first quick exit too (a worker killed while it started).
                delay = (
                    min(2.0 ** (program.quick_exits - 2), MAX_RESTART_DELAY_S)
                    if program.quick_exits > 1
                    else 0.0
                )
                self.say(
                    f"supervisor: {program.name} (pid {process.pid}) exited with "
                    f"{process.returncode}; restarting in {delay:.0f} s"
                )
                program.restart_at = now + delay

    def stop(self) -> None:
        """SIGTERM to every program's group; after the grace period, SIGKILL what is left."""
        self._stopping = True
        running = [p.process for p in self.programs if p.process is not None]
        for process in running:
            _signal_group(process, signal.SIGTERM)
        deadline = time.monotonic() + self.grace_s
        while time.monotonic() < deadline and any(p.poll() is None for p in running):
            time.sleep(0.05)
        for process in running:
            # Also when the leader has exited: what it started may still be in its group.
            _signal_group(process, signal.SIGKILL)
            if process.poll() is None:
                process.wait()


def _signal_group(process: subprocess.Popen, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, sig)  # the group's id is the leader's pid (process_group=0)
