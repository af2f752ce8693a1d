"""Argument types shared by the ``vtlearn`` subcommands.

Every integer option of the CLI states its minimum through :func:`count` (or :func:`counts` for a
comma-separated list of them), so that a negative or zero count is refused by argparse with the flag's name
(``argument --seeds: must be >= 1, got -1``) before any work starts, instead of surfacing later as an
``IndexError`` or a silently empty run. A float option states its range through :func:`real`, and a list of
procedural categories is read by :func:`category_list`, whose errors name the flag.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Mapping

from vtlearn.bench_utils import csv_list
from vtlearn.validation import as_real


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


def counts(minimum: int = 1) -> Callable[[str], list[int]]:
    """An argparse ``type`` for a comma-separated list of integers, each ``>= minimum`` (``--sizes 20,40``).

    Every item is parsed by :func:`count`, so ``--sizes 20,abc`` is refused by argparse with the flag's
    name (``argument --sizes: expected an integer, got 'abc' (a comma-separated list of integers >= 3)``);
    an empty list is refused too.
    """
    one = count(minimum)
    what = f"a comma-separated list of integers >= {minimum}"

    def parse(text: str) -> list[int]:
        items = [x.strip() for x in text.split(",") if x.strip()]
        if not items:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        try:
            return [one(x) for x in items]
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{exc} ({what})") from None

    parse.__name__ = f"list of integers >= {minimum}"
    parse.minimum = minimum  # type: ignore[attr-defined]  # read by the CLI's tests
    return parse


def with_flag(exc: Exception, flags: Mapping[str, str]) -> Exception | None:
    """``exc``, an error whose message starts ``"key: ..."`` (a config field or a function argument), made
    again with the command-line flag ``flags[key]`` in place of ``key``; None when it names no key of
    ``flags``. Commands map their flags onto the arguments they pass on, so the user reads the flag typed."""
    key, sep, rest = str(exc).partition(": ")
    if sep and key.strip() in flags:
        return type(exc)(f"{flags[key.strip()]}: {rest}")
    return None


def real(low: float = -math.inf, high: float = math.inf, *, open_low: bool = False,
         open_high: bool = False) -> Callable[[str], float]:
    """An argparse ``type``: a finite float in ``[low, high]`` (an end excluded with ``open_low`` /
    ``open_high``), checked by
    :func:`~vtlearn.validation.as_real`, so that argparse refuses NaN, inf or a value out of range with the
    flag's name (``argument --coverage-radius: need a finite number > 0, got -1.0``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        try:
            return as_real(value, "value", low=low, high=high, open_low=open_low, open_high=open_high)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix("value: ")) from None

    parse.__name__ = "number"
    return parse


def category_list(
    text: str, flag: str, *, transparent: bool | None = None, empty_ok: bool = False
) -> list[str]:
    """The sim_data categories of a comma-separated ``flag`` value; a ``ValueError`` naming ``flag`` for an
    unknown category, for an empty list (unless ``empty_ok``) and, with ``transparent`` True (False), for a
    category that has no transparent (opaque) instances."""
    from vtlearn.sim_data.shapes import CATEGORIES, TRANSPARENT_PROB

    cats = csv_list(text)
    if not cats and not empty_ok:
        raise ValueError(f"{flag}: no category given; expected comma-separated categories of {CATEGORIES}")
    unknown = [c for c in cats if c not in CATEGORIES]
    if unknown:
        raise ValueError(f"{flag}: unknown {unknown}, expected some of {CATEGORIES}")
    if transparent is not None:
        kind = "transparent" if transparent else "opaque"
        has = [c for c in CATEGORIES if (TRANSPARENT_PROB.get(c, 0.0) > 0 if transparent
                                         else TRANSPARENT_PROB.get(c, 0.0) < 1)]
        bad = [c for c in cats if c not in has]
        if bad:
            raise ValueError(f"{flag}: {bad} have no {kind} instances; categories with some: {has}")
    return cats
