"""Spawned worker processes that stop at once on Ctrl-C, for ``gen-data``'s shards and the benches' jobs.

Ctrl-C reaches every process of the terminal's process group. A :class:`ProcessPoolExecutor` worker catches
whatever its job raises, KeyboardInterrupt and Lightning's exit after one included, sends it back, and takes
the next queued job; and leaving the executor waits for every queued job. So after a Ctrl-C the parent would
wait for the rest of the work (every remaining training of a bench). In :func:`worker_pool` the workers
ignore Ctrl-C (they start with it blocked, so not even one still starting prints a traceback), and the parent,
on Ctrl-C, terminates them and drops the queued jobs. A worker also ends when the parent has ended in a way
that stopped no worker (SIGKILL, an unhandled SIGTERM): it does not train on as an orphan.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor

__all__ = ["exit_with_parent", "worker_pool"]


class _Executor(ProcessPoolExecutor):
    """A spawn-context :class:`ProcessPoolExecutor` whose ``submit`` (where it spawns its workers, one per
    submit until it has them all) holds SIGINT blocked: a worker inherits the blocked signal through fork
    and exec, so a Ctrl-C while it still starts (importing the main module, before the initializer) does not
    reach it. The parent gets a Ctrl-C of that moment as soon as ``submit`` returns."""

    def submit(self, fn, /, *args, **kwargs):
        import signal

        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            return super().submit(fn, *args, **kwargs)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _init_worker(parent: int) -> None:
    """Worker initializer. Only the parent handles Ctrl-C (it stops the workers), so a worker ignores it and
    prints no KeyboardInterrupt traceback of its own. And a worker ends when its parent, the process
    ``parent``, has ended, however that ended (:func:`exit_with_parent`)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_with_parent(parent)


def exit_with_parent(parent: int, period_s: float = 0.2) -> None:
    """End this process (``os._exit(1)``) within ``period_s`` of its parent's end, from a daemon thread that
    watches ``os.getppid()``.

    A parent ended by a signal it cannot handle (SIGKILL; SIGTERM from a scheduler, ``kill`` or a machine
    taken back, which Python does not catch) stops no worker, and a worker spawned with SIGINT blocked does
    not see a Ctrl-C either. Without this thread an orphaned worker trained on to the end of its job (and
    Lightning, which catches SIGTERM during a fit, kept it going past a SIGTERM of the whole process group).
    A rerun of the bench then found the orphan training beside it and writing into the same loop state. The
    state files are written atomically, so ending at any moment loses only the job under way. The progress
    manager of :mod:`vtlearn.job_progress` runs it too, or it would idle on for ever.
    """
    import os
    import threading
    import time

    from vtlearn.validation import as_int, as_real

    parent = as_int(parent, "parent")
    period_s = as_real(period_s, "period_s", low=0.0, open_low=True)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(period_s)
        os._exit(1)

    threading.Thread(target=watch, name="vtlearn-exit-with-parent", daemon=True).start()


def _stop_pool(ex: ProcessPoolExecutor, workers_before: set[int]) -> None:
    """Stop ``ex`` now: its worker processes are terminated and its queued jobs dropped.

    The workers are this process's children that were not running before the pool was made
    (``workers_before``, pids from ``multiprocessing.active_children()``): Python < 3.14 has no public call
    that terminates an executor's workers, and ``shutdown`` alone waits for the running jobs.
    """
    import multiprocessing as mp

    for proc in mp.active_children():
        if proc.pid not in workers_before:
            proc.terminate()
    ex.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A :class:`ProcessPoolExecutor` of ``workers`` spawned processes that ignore Ctrl-C, from their start
    (they are spawned with SIGINT blocked) to their end, and that end when this process has ended
    (:func:`exit_with_parent`).

    On leaving the block:

    - normally, it waits for every job;
    - on Ctrl-C, or when a generator that yields from the block is closed before its end (its consumer
      stopped, on an error or a Ctrl-C of its own), it terminates the workers at once and drops the queued
      jobs;
    - on another error, it drops the queued jobs and waits for the running ones (they may be writing files),
      unless a Ctrl-C comes meanwhile; the error is raised either way.

    Make the pool after any helper process of the caller's (a multiprocessing manager): the children running
    when it is made are not its workers, and are left alone.
    """
    import multiprocessing as mp
    import os

    before = {p.pid for p in mp.active_children()}
    ex = _Executor(workers, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                   initargs=(os.getpid(),))
    try:
        yield ex
    except (KeyboardInterrupt, GeneratorExit):
        _stop_pool(ex, before)
        raise
    except BaseException as exc:
        try:
            ex.shutdown(wait=True, cancel_futures=True)
        except KeyboardInterrupt:
            _stop_pool(ex, before)
            raise exc from None  # the job's error, not the interrupt, is what the user must see
        raise
    ex.shutdown(wait=True)
