"""Torch's intra-op thread count, given back to the caller after code that sets it for itself.

Several commands take ``--threads`` and call ``torch.set_num_threads`` (a bench job, ``recognize``,
``reconstruct``, the quickstart). Run as a process that ends there, that is harmless; called from Python
(``vtlearn.cli.main([...])``, ``run_quickstart``, an in-process bench job) the count would stay set for the
caller. :func:`keep_torch_threads` puts it back.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator

__all__ = ["keep_torch_threads"]


@contextlib.contextmanager
def keep_torch_threads() -> Iterator[None]:
    """Restore torch's thread count on exit, also after an exception or a Ctrl-C.

    It imports nothing: when torch is not imported on entry, the caller has no count to keep and the block
    runs as it is (``vtlearn --help`` stays free of the torch import).
    """
    torch = sys.modules.get("torch")
    threads = torch.get_num_threads() if torch is not None else None
    try:
        yield
    finally:
        if threads is not None:
            torch.set_num_threads(threads)
