"""The finished jobs of a long bench, kept on disk as each one ends, so that a bench stopped part-way (Ctrl-C,
a crash, a machine taken back) goes on from where it stopped when the same command runs again.

``bench crossmodal`` and ``bench active-learning`` run tens of trainings, for minutes to hours. Their
``--json`` is written once, at the end; until then the finished trainings live in a journal folder beside it,
``<json without .json>.jobs/``:

- ``jobs.jsonl``: one JSON line per finished job, ``{"key", "result", "arrays"}``, appended and fsync'ed as
  the job ends;
- ``<key>.npz``: the job's arrays, where it has any (the t-SNE figure's features), written atomically with
  ``allow_pickle=False`` before its line, whose ``arrays`` entry holds the file's SHA-256;
- ``<key>.partial/``: what a job that keeps its own state while it runs (an active-learning loop, round by
  round: :class:`vtlearn.active.learning_loop.ActiveLearningLoop`'s ``state_dir``) has kept so far; removed
  once the job's line is written. A stopped bench's rerun hands it back to the job, which goes on from it
  (or, when it cannot be used, drops it and starts again);
- ``<name>.kept/``: where asked (``bench active-learning --keep-loops``), a finished job's last state, moved
  there from its ``.partial/`` under a name that leaves out the settings a longer run may change (the number
  of rounds). A job of another key under that name that has no state of its own starts from a copy (a loop
  given more rounds goes on from the kept one's last round), and its last state then takes the name's
  place. A folder holding kept states is not removed at the end of a bench;
- ``lock``: held (``flock``) by the bench writing the folder, so that a second bench started with the same
  ``--json`` is refused instead of mixing its jobs in and removing the folder under the first.

A job's key is the SHA-256 of the canonical JSON of everything that decides its result: the bench, the job's
function and arguments, the row's model settings, the data's fingerprint, the versions of vtlearn and torch,
the digest of vtlearn's own code (:func:`source_digest`, so that an edit to the code under the same version
number trains again, and one to a docstring or comment does not) and the vector capability of torch's CPU
kernels. A rerun with other settings therefore finds no finished job of its own and trains everything; one
with more seeds or rows reuses the jobs it shares with the stopped run.
A line cut short by a kill, or whose arrays file is missing or changed, is not a finished job: that job runs
again. Nothing in the folder is executed or unpickled. The folder is removed once the bench has written its
``--json`` (and figures), unless it holds kept states; ``--fresh`` empties it before the run.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from vtlearn.io import sha256_file

__all__ = ["JobJournal", "JournalledJobs", "job_key", "journal_folder", "source_digest"]

_LINES = "jobs.jsonl"
_LOCK = "lock"
_KEY = re.compile(r"[0-9a-f]{64}")


def _file_name(name: Any, what: str) -> str:
    """``name`` as one component of a path inside the journal folder: a ValueError naming ``what`` for an
    empty name, ``.`` or ``..``, or one with a path separator (it would reach outside the folder)."""
    if (not isinstance(name, str) or name in ("", ".", "..") or "/" in name
            or (os.altsep is not None and os.altsep in name) or os.sep in name):
        raise ValueError(f"{what}: need a file name within the journal folder, got {name!r}")
    return name


def journal_folder(json_path) -> Path:
    """The journal folder of a bench writing ``json_path``: beside it, named after it without ``.json`` and
    with ``.jobs`` (``runs/bench/cm.json`` -> ``runs/bench/cm.jobs``)."""
    p = Path(json_path)
    return p.with_name(p.stem + ".jobs") if p.suffix == ".json" else p.with_name(p.name + ".jobs")


def _code_of(data: bytes) -> bytes:
    """What a Python file runs: its syntax tree without line numbers, docstrings or comments (``ast.dump``),
    so that an edit to a docstring, a comment or the layout leaves it unchanged. A file that does not parse
    counts by its bytes."""
    import ast

    try:
        tree = ast.parse(data)
    except (SyntaxError, ValueError):
        return data
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()


_CODE_DIGESTS: dict[bytes, bytes] = {}  # SHA-256 of a file's bytes -> SHA-256 of its _code_of


def source_digest() -> str:
    """The SHA-256 (hex) of vtlearn's Python code: every ``.py`` file of the installed package, by its path
    within the package and its syntax tree without docstrings and comments (:func:`_code_of`), in path order.
    Part of the benches' job keys, so that a job kept before an edit to the code is trained again rather than
    mixed with jobs of the edited code, while an edit to a docstring, a comment or the layout keeps them.

    Parsing the package takes about a second; the tree's digest is kept for the process under the digest of
    the file's bytes, so a later call costs a few milliseconds."""
    import vtlearn

    root = Path(vtlearn.__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix().encode()
        h.update(len(rel).to_bytes(4, "little") + rel)
        data = path.read_bytes()
        raw = hashlib.sha256(data).digest()
        if raw not in _CODE_DIGESTS:
            _CODE_DIGESTS[raw] = hashlib.sha256(_code_of(data)).digest()
        h.update(_CODE_DIGESTS[raw])
    return h.hexdigest()


def job_key(*parts: Any) -> str:
    """The SHA-256 (hex) of the canonical JSON of ``parts`` (dict keys sorted, tuples as lists, numpy values
    as Python ones); equal parts give equal keys in every process and on every machine."""
    from vtlearn.bench_utils import to_jsonable

    text = json.dumps(to_jsonable(list(parts)), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


class JobJournal:
    """The finished jobs of one bench run kept in ``folder`` (see the module docstring for its layout).

    ``fresh``: discard what the folder holds first (``--fresh``). :meth:`finished` reads the jobs kept by an
    earlier run; :meth:`add` keeps one more; :meth:`discard` removes the folder once the bench's results are
    written. The journal holds the folder's lock from its creation until :meth:`discard` or :meth:`release`
    (or the process's end): a second journal of the same folder is refused meanwhile.

    Example::

        journal = JobJournal(journal_folder("runs/bench/cm.json"))
        done = journal.finished()               # {key: (result, arrays)}
        journal.add(key, {"acc": 71.2}, {"features": feats})
    """

    def __init__(self, folder, fresh: bool = False) -> None:
        self.folder = Path(folder)
        if self.folder.exists() and not self.folder.is_dir():
            raise ValueError(f"--json: the bench keeps its finished jobs in {self.folder}, which is a file; "
                             "move it or choose another --json")
        self.lines = self.folder / _LINES
        self._lock = self._take_lock()
        if fresh:
            for entry in self.folder.iterdir():
                if entry.name != _LOCK:
                    shutil.rmtree(entry) if entry.is_dir() else entry.unlink()

    def _take_lock(self):
        """The open lock file, locked (``flock``, released by the kernel when the process ends, however it
        ends); a ValueError naming ``--json`` when another bench holds it. None where ``fcntl`` is missing."""
        try:
            import fcntl
        except ImportError:  # not POSIX: no lock, as before
            return None
        self.folder.mkdir(parents=True, exist_ok=True)
        fh = open(self.folder / _LOCK, "a")
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise ValueError(f"--json: another bench writing the same --json is running (it holds "
                             f"{self.folder / _LOCK}); wait for it to end, or choose another --json") \
                from None
        return fh

    def partial_dir(self, key: str) -> Path:
        """The folder in which the job ``key`` keeps its state while it runs (see the module docstring)."""
        return self.folder / f"{_file_name(key, 'key')}.partial"

    def kept_dir(self, name: str) -> Path:
        """The folder in which a finished job's last state is kept under ``name`` (see the module
        docstring)."""
        return self.folder / f"{_file_name(name, 'name')}.kept"

    def kept_states(self) -> list[Path]:
        """The kept states the folder holds (:meth:`kept_dir`), sorted."""
        return sorted(self.folder.glob("*.kept")) if self.folder.is_dir() else []

    def finished(self) -> dict[str, tuple[Any, dict[str, np.ndarray] | None]]:
        """``{key: (result, arrays or None)}`` of every job the folder holds whole: lines that do not parse (a
        write cut short) and jobs whose arrays file is missing or does not match its checksum are left out,
        so those jobs run again."""
        out: dict[str, tuple[Any, dict[str, np.ndarray] | None]] = {}
        if not self.lines.is_file():
            return out
        for line in self.lines.read_text(errors="replace").splitlines():
            try:
                entry = json.loads(line)
                key, result, arrays = entry["key"], entry["result"], entry["arrays"]
            except (json.JSONDecodeError, KeyError, TypeError):
                continue
            if not (isinstance(key, str) and _KEY.fullmatch(key)):  # keys are job_key's: no path in them
                continue
            if arrays is None:
                out[key] = (result, None)
                continue
            path = self.folder / f"{key}.npz"
            try:
                if not path.is_file() or sha256_file(path) != arrays.get("sha256"):
                    continue
                with np.load(path, allow_pickle=False) as z:
                    out[key] = (result, {k: z[k] for k in z.files})
            except (OSError, ValueError, AttributeError):
                continue
        return out

    def add(self, key: str, result: Any, arrays: dict[str, np.ndarray] | None = None,
            keep_as: str | None = None) -> None:
        """Keep a finished job: its ``arrays`` (name -> numeric array) as ``<key>.npz``, written atomically,
        then its line, ``result`` as JSON (numpy values converted, NaN kept), appended and fsync'ed.
        ``keep_as``: the job's last state (its :meth:`partial_dir`) then takes the place of the state kept
        under that name (:meth:`kept_dir`); without it the state is removed."""
        from vtlearn.bench_utils import to_jsonable
        from vtlearn.io import atomic_write_npz

        self.folder.mkdir(parents=True, exist_ok=True)
        stored = None
        if arrays is not None:
            path = atomic_write_npz(self.folder / f"{key}.npz", **arrays)
            stored = {"file": path.name, "sha256": sha256_file(path)}
        line = json.dumps({"key": key, "result": to_jsonable(result, nan_as_null=False), "arrays": stored})
        with open(self.lines, "a+b") as fh:
            fh.seek(0, os.SEEK_END)
            if fh.tell():  # a line cut short by a kill ends where this one would start: end it first
                fh.seek(-1, os.SEEK_END)
                cut = fh.read(1) != b"\n"
                fh.seek(0, os.SEEK_END)
                if cut:
                    fh.write(b"\n")
            fh.write(line.encode() + b"\n")
            fh.flush()
            os.fsync(fh.fileno())
        partial = self.partial_dir(key)
        if keep_as is not None and partial.is_dir():
            kept = self.kept_dir(keep_as)
            old = kept.with_name(kept.name + ".old")
            shutil.rmtree(old, ignore_errors=True)
            if kept.is_dir():  # moved aside, not removed, until the new state stands in its place
                os.replace(kept, old)
            os.replace(partial, kept)
            shutil.rmtree(old, ignore_errors=True)
        shutil.rmtree(partial, ignore_errors=True)  # the job's line now stands for it

    def finish(self) -> list[Path]:
        """The end of a bench that has written its ``--json``: remove the folder, unless it holds kept states
        (:meth:`kept_states`, which a later run goes on from), which are returned; then only the lock goes."""
        kept = self.kept_states()
        if kept:
            self.release()
        else:
            self.discard()
        return kept

    def discard(self) -> None:
        """Remove the folder and everything in it (nothing happens when there is none); let its lock go."""
        if self.folder.is_dir():
            shutil.rmtree(self.folder)
        self.release()

    def release(self) -> None:
        """Let the folder's lock go, and remove the folder if it holds nothing else (no job was kept)."""
        if self._lock is None:
            return
        self._lock.close()
        self._lock = None
        if self.folder.is_dir() and [p.name for p in self.folder.iterdir()] == [_LOCK]:
            shutil.rmtree(self.folder, ignore_errors=True)


def _keyed(key: str, state_dir: Path | None, fn: Callable, *args, progress=None):
    """``(key, fn(*args, progress=progress))``, with ``state_dir=state_dir`` too unless it is None: tells the
    journal which job a result from a worker (they arrive in completion order) belongs to. Module level, so
    that spawned workers can run it."""
    kwargs = {} if state_dir is None else {"state_dir": state_dir}
    return key, fn(*args, progress=progress, **kwargs)


class JournalledJobs:
    """The results of a bench's jobs, ``fn(*a, progress=sink)`` for every ``a`` in ``job_args`` as
    :func:`vtlearn.job_progress.map_jobs` runs them, where ``keys[i]`` (unique, :func:`job_key`) names the job
    ``job_args[i]``.

    Iterating yields first the jobs ``journal`` holds finished, rebuilt by ``decode(result, arrays)``
    without running (``on_reused(result)`` is called for each, e.g. to move a progress bar by the job's
    epochs), then the others as they end, each kept in the journal as ``encode(result) -> (JSON-able part,
    arrays or None)`` before it is yielded. Leaving the ``with`` block stops any job still running.

    ``bench`` names the command in the lines printed: how many finished jobs are reused, and, when the
    ``with`` block ends on an error or a Ctrl-C, how many are kept and that the same command goes on from
    there (the journal's lock is then let go).

    ``partial=True``: ``fn`` also gets ``state_dir=journal.partial_dir(key)``, a folder in which to keep its
    state while it runs and from which, rerun after a stop, it goes on (the folder is removed once the job's
    result is kept). ``keep_as`` (with ``partial``): one name or None per job; a named job's last state is
    kept under its name once it ends (:meth:`JobJournal.add`), and a named job with no state of its own
    starts from a copy of the one kept under its name, if any.

    Example::

        with JournalledJobs("bench crossmodal", journal, keys, fn, job_args, workers, encode, decode) as jobs:
            for result in jobs:
                ...
    """

    def __init__(self, bench: str, journal: JobJournal, keys: list[str], fn: Callable, job_args: list[tuple],
                 workers: int, encode: Callable[[Any], tuple[Any, dict | None]],
                 decode: Callable[[Any, dict | None], Any], tick: Callable[[int], object] | None = None,
                 on_reused: Callable[[Any], object] | None = None, partial: bool = False,
                 keep_as: list[str | None] | None = None) -> None:
        from vtlearn.job_progress import map_jobs

        self.bench, self.journal, self.keys = bench, journal, keys
        self.encode, self.decode, self.on_reused = encode, decode, on_reused
        try:  # a refusal here ends the bench: let the folder's lock go (and the folder, if it holds nothing)
            if len(keys) != len(job_args) or len(set(keys)) != len(keys):
                raise ValueError(f"keys: need one unique key per job, got {len(set(keys))} distinct for "
                                 f"{len(job_args)} jobs")
            if keep_as is not None and (not partial or len(keep_as) != len(keys)):
                raise ValueError(f"keep_as: need one name or None per job of a partial=True journal, got "
                                 f"{len(keep_as)} for {len(keys)} jobs (partial={partial})")
            self.keep_as = dict(zip(keys, keep_as or [None] * len(keys), strict=True))
            self.done = journal.finished()
            todo = [(k, journal.partial_dir(k) if partial else None, fn, *a)
                    for k, a in zip(keys, job_args, strict=True) if k not in self.done]
            self.resumed = sum(d is not None and d.is_dir() for _, d, *_ in todo)  # jobs with a state kept
            self.from_kept = 0  # jobs that start from a copy of a state kept under their name
            for k, d, *_ in todo:
                name = self.keep_as[k]
                if name is not None and not d.is_dir() and journal.kept_dir(name).is_dir():
                    shutil.copytree(journal.kept_dir(name), d)
                    self.from_kept += 1
            self._running = map_jobs(_keyed, todo, workers, tick)  # checks workers before anything runs
        except BaseException:
            journal.release()
            raise
        self.kept = 0  # jobs in the journal among those yielded so far

    def __enter__(self) -> JournalledJobs:
        from tqdm.auto import tqdm

        reused = sum(k in self.done for k in self.keys)
        if reused:
            tqdm.write(f"{self.bench}: {reused} of {len(self.keys)} jobs finished earlier are reused from "
                       f"{self.journal.folder} (--fresh runs them again)")
        elif self.done:
            tqdm.write(f"{self.bench}: {self.journal.folder} holds {len(self.done)} finished jobs of other "
                       "settings; none is reused")
        if self.resumed:
            tqdm.write(f"{self.bench}: {self.resumed} unfinished jobs go on from the state they kept in "
                       f"{self.journal.folder}")
        if self.from_kept:
            tqdm.write(f"{self.bench}: {self.from_kept} jobs start from the last state of an earlier run, "
                       f"kept in {self.journal.folder}")
        return self

    def __iter__(self) -> Iterator:
        for k in self.keys:
            if k in self.done:
                result = self.decode(*self.done[k])
                if self.on_reused is not None:
                    self.on_reused(result)
                self.kept += 1
                yield result
        for k, result in self._running:
            self.journal.add(k, *self.encode(result), keep_as=self.keep_as[k])
            self.kept += 1
            yield result

    def __exit__(self, exc_type, exc, tb) -> None:
        import sys

        from tqdm.auto import tqdm

        self._running.close()  # a block left early stops the workers (vtlearn.worker_pool)
        if exc_type is None:
            return
        partial = sum(self.journal.partial_dir(k).is_dir() for k in self.keys)
        if self.kept or partial:
            also = f" with the state of {partial} unfinished" if partial else ""
            tqdm.write(f"{self.bench}: {self.kept} of {len(self.keys)} jobs are kept in "
                       f"{self.journal.folder}{also}; the same command goes on from there", file=sys.stderr)
        self.journal.release()
