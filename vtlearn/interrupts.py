"""Ctrl-C where third-party code would swallow it or turn it into another exit.

- trimesh wraps its optional imports (scipy, networkx, PIL, rtree, its path module) in ``except
  BaseException`` and stores the exception in their place. A Ctrl-C in the second its import takes is
  swallowed there: the command runs on, and the names it replaced raise KeyboardInterrupt whenever they are
  used later. :func:`import_trimesh` imports it with Ctrl-C held back, so a Ctrl-C arrives once the import is
  done and stops the command as any other would. The ``vtlearn`` command and ``train.py`` call it first.
- Lightning's Trainer answers a Ctrl-C with a graceful shutdown and then calls ``sys.exit(1)``.
  :func:`lightning_interrupt_as_keyboard_interrupt` turns that exit back into KeyboardInterrupt, so a
  ``vtlearn`` command that trains in its own process ends as any other interrupted command does (one line,
  exit code 130), and ``vtlearn.cli.main`` returns 130 to a Python caller instead of raising SystemExit.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

__all__ = ["import_trimesh", "lightning_interrupt_as_keyboard_interrupt", "sigint_held"]


@contextlib.contextmanager
def sigint_held() -> Iterator[None]:
    """Hold a Ctrl-C back until the block ends, then deliver it to the handler in place before.

    Python's default handler then raises KeyboardInterrupt; an ignored SIGINT stays ignored. Only the main
    thread can set a signal handler, and a handler not installed from Python (an embedding program's) could
    not be put back; in either case the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        yield
        return
    pending: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pending:
        signal.raise_signal(signal.SIGINT)


def import_trimesh() -> None:
    """Import trimesh with Ctrl-C held back (a no-op once it is imported)."""
    with sigint_held():
        import trimesh  # noqa: F401


@contextlib.contextmanager
def lightning_interrupt_as_keyboard_interrupt() -> Iterator[None]:
    """Raise KeyboardInterrupt where a Lightning training in the block exits after a Ctrl-C.

    Lightning calls ``sys.exit(1)`` in its ``except KeyboardInterrupt`` block, so that exit is the
    SystemExit whose context is a KeyboardInterrupt; any other exit passes as it is.
    """
    try:
        yield
    except SystemExit as exc:
        if isinstance(exc.__context__, KeyboardInterrupt):
            raise KeyboardInterrupt from None
        raise
