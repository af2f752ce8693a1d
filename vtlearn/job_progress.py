"""The benches' jobs, run in this process or in spawned worker processes, with a progress bar that moves while
they train.

A bench job is a whole training (or a whole active-learning run), minutes long, so a bar that moves once per
job stands still for most of a bench. Here every job gets a *sink* with a ``put(n)`` method. Its trainer's
:class:`TickCallback` puts a tick into it after each epoch (or each training), and the parent process turns
the ticks into ``tick(n)`` calls, typically a tqdm bar's ``update``. In this process the sink calls ``tick``
directly. In spawned workers it is a manager queue, which the parent drains twice a second while it waits
for results.

The ticks change nothing in the trainings: the callback draws no random numbers and touches no tensor, and
the bench tests check that runs with and without workers give the same numbers.
"""

from __future__ import annotations

import queue
from collections.abc import Callable, Iterator

import lightning as L

__all__ = ["LocalSink", "TickCallback", "map_jobs"]

#: how often (seconds) the parent drains the workers' ticks while it waits for a job to finish
POLL_S = 0.5


class LocalSink:
    """A sink for a job run in this process: ``put(n)`` calls ``tick(n)`` at once."""

    def __init__(self, tick: Callable[[int], object]) -> None:
        self._tick = tick

    def put(self, n: int = 1) -> None:
        self._tick(n)


class TickCallback(L.Callback):
    """Puts a tick into ``sink`` after every training epoch (``every="epoch"``) or at the end of every fit
    (``every="fit"``: one tick per training, for jobs whose trainings differ in length)."""

    def __init__(self, sink, every: str = "epoch") -> None:
        if every not in ("epoch", "fit"):
            raise ValueError(f"every: expected 'epoch' or 'fit', got {every!r}")
        if not callable(getattr(sink, "put", None)):
            raise ValueError(f"sink: needs a put(n) method, got {type(sink).__name__}")
        self.sink, self.every = sink, every

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.every == "epoch":
            self.sink.put(1)

    def on_fit_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.every == "fit":
            self.sink.put(1)


def _drain(sink, tick: Callable[[int], object]) -> None:
    while True:
        try:
            n = sink.get_nowait()
        except queue.Empty:
            return
        tick(n)


def map_jobs(fn: Callable, job_args: list[tuple], workers: int,
             tick: Callable[[int], object] | None = None) -> Iterator:
    """An iterator of ``fn(*a, progress=sink)`` for every tuple ``a`` in ``job_args``: in this process, in
    order, or in ``workers`` spawned processes, in completion order (``fn`` must then be a module-level
    function). ``sink`` is ``None`` without ``tick``; with it, every ``sink.put(n)`` of a job reaches
    ``tick(n)`` in this process while the job runs. ``workers`` is checked here, before any job runs.
    A job may set torch's thread count for itself (the benches' ``--threads``); in this process it is put
    back after each job, so the caller keeps its own.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"--workers: need >= 1, got {workers}")
    if workers == 1:
        return _map_here(fn, job_args, LocalSink(tick) if tick is not None else None)
    return _map_in_processes(fn, job_args, workers, tick)


def _map_here(fn: Callable, job_args: list[tuple], sink) -> Iterator:
    from vtlearn.torch_threads import keep_torch_threads

    for a in job_args:
        with keep_torch_threads():
            result = fn(*a, progress=sink)
        yield result


def _map_in_processes(fn: Callable, job_args: list[tuple], workers: int,
                      tick: Callable[[int], object] | None) -> Iterator:
    import multiprocessing as mp
    import os
    from concurrent.futures import FIRST_COMPLETED, wait
    from multiprocessing.managers import SyncManager

    from vtlearn.worker_pool import exit_with_parent, worker_pool

    manager = None
    if tick is not None:  # its server process ends with this one, as the workers do
        manager = SyncManager(ctx=mp.get_context("spawn"))
        manager.start(exit_with_parent, (os.getpid(),))
    try:
        sink = manager.Queue() if manager is not None else None
        # Ctrl-C stops the workers at once; a failed job drops the queued ones (worker_pool)
        with worker_pool(workers) as ex:
            pending = {ex.submit(fn, *a, progress=sink) for a in job_args}
            while pending:
                done, pending = wait(pending, timeout=POLL_S if sink is not None else None,
                                     return_when=FIRST_COMPLETED)
                if sink is not None:
                    _drain(sink, tick)
                for fut in done:
                    yield fut.result()
            if sink is not None:
                _drain(sink, tick)
    finally:
        if manager is not None:
            manager.shutdown()
