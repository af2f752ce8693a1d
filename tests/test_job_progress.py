"""Tests for vtlearn.job_progress: the benches' jobs tick a progress bar while they train."""

import contextlib
import os
import signal
import subprocess
import sys
import time

import lightning as L
import pytest
import torch
from _interrupt import env_with_path, interrupt_once_started
from torch.utils.data import DataLoader, TensorDataset

from vtlearn.job_progress import LocalSink, TickCallback, map_jobs


class _Tiny(L.LightningModule):
    def __init__(self):
        super().__init__()
        self.lin = torch.nn.Linear(2, 1)

    def training_step(self, batch, batch_idx):
        x, y = batch
        return torch.nn.functional.mse_loss(self.lin(x), y)

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def _fit(epochs, callbacks):
    torch.manual_seed(0)
    data = TensorDataset(torch.randn(8, 2), torch.randn(8, 1))
    model = _Tiny()
    L.Trainer(max_epochs=epochs, logger=False, enable_checkpointing=False, enable_progress_bar=False,
              enable_model_summary=False, callbacks=callbacks).fit(model, DataLoader(data, batch_size=4))
    return model.lin.weight.detach().clone()


def test_tick_callback_ticks_once_per_epoch_or_once_per_fit_and_changes_nothing():
    ticks = []
    weights = _fit(3, [TickCallback(LocalSink(ticks.append))])
    assert ticks == [1, 1, 1]
    ticks.clear()
    _fit(3, [TickCallback(LocalSink(ticks.append), every="fit")])
    assert ticks == [1]
    assert torch.equal(weights, _fit(3, []))  # the same training without the callback


def test_tick_callback_and_map_jobs_refuse_bad_arguments():
    with pytest.raises(ValueError, match="every"):
        TickCallback(LocalSink(print), every="step")
    with pytest.raises(ValueError, match="sink"):
        TickCallback(object())
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="--workers"):
            map_jobs(divmod, [(1, 2)], bad)


def _job(epochs, progress=None):
    return _fit(epochs, [TickCallback(progress)] if progress is not None else []).sum().item(), epochs


def test_map_jobs_in_this_process_passes_the_sink_and_keeps_the_order():
    ticks = []
    out = list(map_jobs(_job, [(2,), (1,), (3,)], 1, tick=ticks.append))
    assert [e for _, e in out] == [2, 1, 3] and sum(ticks) == 6
    assert list(map_jobs(_job, [(2,)], 1)) == [out[0]]  # no tick: no sink


def _threads_job(threads, fail=False, progress=None):
    torch.set_num_threads(threads)
    if fail:
        raise RuntimeError("the job failed")
    return torch.get_num_threads()


def test_map_jobs_in_this_process_gives_the_callers_thread_count_back():
    """A job that sets torch's thread count (the benches' --threads) runs with it, and the caller has its own
    back after each job, also after a job that raised (run in-process, a bench used to leave the caller
    on its jobs' count)."""
    before = torch.get_num_threads()
    other = 1 if before > 1 else 2
    try:
        jobs = map_jobs(_threads_job, [(other,), (other,)], 1)
        assert next(jobs) == other and torch.get_num_threads() == before
        assert next(jobs) == other and torch.get_num_threads() == before
        with pytest.raises(RuntimeError, match="the job failed"):
            list(map_jobs(_threads_job, [(other, True)], 1))
        assert torch.get_num_threads() == before
    finally:
        torch.set_num_threads(before)


_SLOW_JOB = """
import time
from pathlib import Path


def job(i, folder, progress=None):
    (Path(folder) / f"started-{i}").touch()
    time.sleep(60.0)
    return i
"""


def test_ctrl_c_stops_the_workers_at_once_and_drops_the_queued_jobs(tmp_path):
    # a worker took whatever its job raised, KeyboardInterrupt and Lightning's exit after one included, and
    # went on with the next job, and leaving the pool waited for them all: a bench's Ctrl-C hung for every
    # remaining training. The tick makes a manager process run beside the workers, as in the benches.
    (tmp_path / "slow_job.py").write_text(_SLOW_JOB)
    code = ("import sys; import slow_job; from vtlearn.job_progress import map_jobs; "
            "list(map_jobs(slow_job.job, [(i, sys.argv[1]) for i in range(6)], 2, tick=print))")
    returncode, err, seconds = interrupt_once_started(code, tmp_path, workers=2)
    assert seconds < 10  # each job sleeps 60 s
    assert returncode != 0 and err.count("KeyboardInterrupt") == 1, err
    assert len(list(tmp_path.glob("started-*"))) == 2  # the queued jobs never started


_PID_JOB = """
import os
import time
from pathlib import Path


def job(i, folder, progress=None):
    (Path(folder) / f"started-{i}").write_text(str(os.getpid()))
    time.sleep(60.0)
    return i
"""


def _stat(pid: int) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (state, ppid, ...), or None."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        return None


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, ended and not reaped by a parent that does not reap, does
    not)."""
    fields = _stat(pid)
    return fields is not None and fields[0] != "Z"


def _children(pid: int) -> list[int]:
    return [int(d) for d in os.listdir("/proc") if d.isdigit() and (f := _stat(int(d))) and f[1] == str(pid)]


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads process states from /proc")
def test_the_workers_end_when_their_parent_is_killed(tmp_path):
    # a parent ended by SIGKILL (or a SIGTERM, which Python does not catch) stopped no worker: each trained
    # on to the end of its job as an orphan, beside a rerun of the bench and in the same loop states; the
    # progress manager (tick) idled on for ever
    (tmp_path / "pid_job.py").write_text(_PID_JOB)
    code = ("import sys; import pid_job; from vtlearn.job_progress import map_jobs; "
            "list(map_jobs(pid_job.job, [(i, sys.argv[1]) for i in range(2)], 2, tick=print))")
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], env=env_with_path(tmp_path),
                            start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pids: list[int] = []
    try:
        deadline = time.monotonic() + 60.0
        while len(pids) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
            pids = [int(t) for f in tmp_path.glob("started-*") if (t := f.read_text())]
        assert len(pids) == 2 and all(map(_alive, pids)), pids
        pids = _children(proc.pid)  # the workers, the manager and multiprocessing's resource tracker
        assert len(pids) >= 3, pids
        proc.kill()  # the parent alone, as `kill -9` or the OOM killer ends it
        proc.wait()
        deadline = time.monotonic() + 10.0  # each job sleeps 60 s
        while any(map(_alive, pids)) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(map(_alive, pids)), [p for p in pids if _alive(p)]
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def test_exit_with_parent_refuses_a_bad_parent_or_period():
    from vtlearn.worker_pool import exit_with_parent

    for kwargs, name in ((dict(parent=0), "parent"), (dict(parent="1"), "parent"),
                         (dict(parent=1, period_s=0.0), "period_s"),
                         (dict(parent=1, period_s=-1), "period_s")):
        with pytest.raises(ValueError, match=name):
            exit_with_parent(**kwargs)


_FIRST_JOB_QUICK = """
import time


def job(i, progress=None):
    if i > 0:
        time.sleep(60.0)
    return i
"""


def test_a_consumer_that_stops_early_stops_the_workers_at_once(tmp_path, monkeypatch):
    # the bench's loop over the results ended (an error, or a Ctrl-C outside the pool's wait): closing the
    # iterator waited for the running jobs, whose workers ignore Ctrl-C
    (tmp_path / "first_job_quick.py").write_text(_FIRST_JOB_QUICK)
    monkeypatch.syspath_prepend(str(tmp_path))
    import first_job_quick

    results = map_jobs(first_job_quick.job, [(i,) for i in range(4)], 2)
    assert next(results) == 0
    start = time.monotonic()
    results.close()
    assert time.monotonic() - start < 10  # the running job sleeps 60 s


# A main script whose import takes a second in a spawned worker (as `vtlearn`'s, which imports vtlearn.cli
# there, before the pool's initializer runs); the parent sends each starting worker a Ctrl-C meanwhile, as a
# terminal's Ctrl-C reaches every process of the group, and then waits for the jobs.
_SLOW_MAIN = """
import multiprocessing as mp
import os
import signal
import sys
import time

if __name__ == "__mp_main__":
    time.sleep(1.0)  # a worker still starting


def job(x):
    return 2 * x


if __name__ == "__main__":
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.default_int_handler)
    from vtlearn.worker_pool import worker_pool

    with worker_pool(2) as ex:
        futures = [ex.submit(job, x) for x in (1, 2)]
        for proc in mp.active_children():
            os.kill(proc.pid, signal.SIGINT)
        print([f.result() for f in futures])
"""


def test_ctrl_c_while_the_workers_still_start_reaches_no_worker(tmp_path):
    # a worker spawned with Ctrl-C deliverable took it before the pool's initializer had it ignored: it
    # printed a KeyboardInterrupt traceback of its own under the command's interrupted line
    import subprocess
    import sys

    (tmp_path / "slow_main.py").write_text(_SLOW_MAIN)
    out = subprocess.run([sys.executable, str(tmp_path / "slow_main.py")], capture_output=True, text=True,
                         timeout=60, cwd=tmp_path)
    assert (out.returncode, out.stdout, out.stderr) == (0, "[2, 4]\n", "")
