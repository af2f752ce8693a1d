"""Argument types shared by the ``vtlearn`` subcommands.

Every integer option of the CLI states its minimum through :func:`count`, so that a negative or zero count
is refused by argparse with the flag's name (``argument --seeds: must be >= 1, got -1``) before any work
starts, instead of surfacing later as an ``IndexError`` or a silently empty run.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable


def count(minimum: int = 1) -> Callable[[str], int]:
    """An argparse ``type`` that parses an integer and refuses values below ``minimum``.

    ``minimum=0`` is for options where 0 has a meaning (a seed, an index, "0: all", "0: skip").
    """

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    parse.__name__ = f"integer >= {minimum}"
    parse.minimum = minimum  # type: ignore[attr-defined]  # read by the CLI's tests
    return parse
