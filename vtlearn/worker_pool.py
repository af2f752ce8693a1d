"""Spawned worker processes that stop at once on Ctrl-C, for ``gen-data``'s shards and the benches' jobs.

Ctrl-C reaches every process of the terminal's process group. A :class:`ProcessPoolExecutor` worker catches
whatever its job raises, KeyboardInterrupt and Lightning's exit after one included, sends it back, and takes
the next queued job; and leaving the executor waits for every queued job. So after a Ctrl-C the parent would
wait for the rest of the work (every remaining training of a bench). In :func:`worker_pool` the workers
ignore Ctrl-C (they start with it blocked, so not even one still starting prints a traceback), and the parent,
on Ctrl-C, terminates them and drops the queued jobs.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor

__all__ = ["worker_pool"]


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


def _ignore_sigint() -> None:
    """Worker initializer: only the parent handles Ctrl-C (it stops the workers), so a worker prints no
    KeyboardInterrupt traceback of its own."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


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
    (they are spawned with SIGINT blocked) to their end.

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

    before = {p.pid for p in mp.active_children()}
    ex = _Executor(workers, mp_context=mp.get_context("spawn"), initializer=_ignore_sigint)
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
