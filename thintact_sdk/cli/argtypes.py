"""Argument types shared by the subcommands (``type=`` of :meth:`argparse.ArgumentParser.add_argument`).

Each converts the option's text or raises :class:`argparse.ArgumentTypeError`, which the
CLI prints as one line naming the option, with exit status 2, before any work is done.
Numbers must be finite: ``nan`` and ``inf`` are refused everywhere.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

MAX_SEED = 2**63 - 1
"""Largest noise seed accepted (numpy generators take any non-negative integer; this keeps
seeds storable as a signed 64-bit number)."""


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _int(text: str) -> int:
    try:
        return int(text, 10)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def finite_float(text: str) -> float:
    """Any finite number."""
    return _float(text)


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """A finite number ≥ 0."""
    value = _float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def int_range(low: int, high: int | None = None) -> Callable[[str], int]:
    """An integer in ``[low, high]`` (no upper bound when ``high`` is None)."""

    def convert(text: str) -> int:
        value = _int(text)
        if value < low or (high is not None and value > high):
            bound = f"between {low} and {high}" if high is not None else f">= {low}"
            raise argparse.ArgumentTypeError(f"must be an integer {bound}, got {text!r}")
        return value

    convert.__name__ = f"int_range({low}, {high})"
    return convert


def float_range(low: float, high: float) -> Callable[[str], float]:
    """A finite number in ``[low, high]``."""

    def convert(text: str) -> float:
        value = _float(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be between {low:g} and {high:g}, got {text!r}")
        return value

    convert.__name__ = f"float_range({low}, {high})"
    return convert


positive_int = int_range(1)
"""An integer ≥ 1 (frame counts, iterations)."""

non_negative_int = int_range(0)
"""An integer ≥ 0."""

seed = int_range(0, MAX_SEED)
"""A random seed: an integer in 0..2**63-1."""
