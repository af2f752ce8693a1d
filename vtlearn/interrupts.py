"""Ctrl-C held back while trimesh imports, so that it is not swallowed.

trimesh wraps its optional imports (scipy, networkx, PIL, rtree, its path module) in ``except BaseException``
and stores the exception in their place. A Ctrl-C in the second its import takes is swallowed there: the
command runs on, and the names it replaced raise KeyboardInterrupt whenever they are used later.
:func:`import_trimesh` imports it with Ctrl-C held back, so a Ctrl-C arrives once the import is done and
stops the command as any other would. The ``vtlearn`` command and ``train.py`` call it first.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

__all__ = ["import_trimesh", "sigint_held"]


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
