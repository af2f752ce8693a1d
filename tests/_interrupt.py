"""Ctrl-C sent to a child Python process once its workers have started a job (for the worker-pool tests)."""

import functools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

# The child starts as an interactive shell starts a command: SIGINT unblocked and at Python's default
# handler, whatever the test process inherited (blocked signals and ignored dispositions survive exec). A
# test run started in the background by a non-interactive shell (`pytest ... &`, as CI runners and `nohup`
# scripts do) has SIGINT ignored from the start (POSIX, for asynchronous commands without job control), so
# without this the child ignored the interrupt: the full-suite failures of stops 69-70.
SIGINT_AS_IN_A_TERMINAL = ("import signal; signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT}); "
                           "signal.signal(signal.SIGINT, signal.default_int_handler); ")


def ended_pid() -> int:
    """The process id of a child interpreter that has ended (a writer that a SIGKILL stopped, for the tests
    of the temporaries it leaves)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def env_with_path(folder: Path) -> dict[str, str]:
    """This process's environment with ``folder`` first on the child interpreter's ``PYTHONPATH``."""
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")]))


def interrupt_once_started(code: str, folder: Path, workers: int) -> tuple[int, str, float]:
    """Run ``code`` in a child interpreter (``folder`` on its path and as its ``sys.argv[1]``) in a process
    group of its own, send the group SIGINT once ``workers`` ``started-*`` files are in ``folder``, and return
    the child's exit code, its stderr and the seconds it took to end after the interrupt.

    The interrupt waits until every worker has taken a job, so that it stops running jobs. Sent while the
    parent still imports, it would test the imports (tests/test_cli.py has those cases); workers that still
    start are tested in test_job_progress.py."""
    proc = subprocess.Popen([sys.executable, "-c", SIGINT_AS_IN_A_TERMINAL + code, str(folder)],
                            env=env_with_path(folder),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60.0  # the workers start and take their first jobs
        def started() -> int:
            return len(list(folder.glob("started-*")))

        while started() < workers and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert started() >= workers and proc.poll() is None, f"{started()} jobs started"
        os.killpg(proc.pid, signal.SIGINT)
        start = time.monotonic()
        _, err = proc.communicate(timeout=30)
        return proc.returncode, err, time.monotonic() - start
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


class CountedCalls:
    """A stand-in for a function (e.g. ``learning_loop.train_and_test``, or a bench's job function) that
    counts its calls in ``calls``, records each call's first two positional arguments in ``seen`` (a bench
    job's (variant or strategy, seed)) and raises ``KeyboardInterrupt``, as a Ctrl-C in that call would, in
    the ``stop_at``-th call or, where ``stop_at`` is a tuple, in the call whose first arguments it is. It
    keeps ``real``'s name, which is part of a bench journal's job key."""

    def __init__(self, real, stop_at: int | tuple | None = None) -> None:
        functools.update_wrapper(self, real)
        self.real, self.stop_at, self.calls, self.seen = real, stop_at, 0, []

    def __call__(self, *args, **kwargs):
        self.calls += 1
        self.seen.append(tuple(args[:2]))
        if self.stop_at in (self.calls, self.seen[-1]):
            raise KeyboardInterrupt
        return self.real(*args, **kwargs)
