"""Types of the numeric command-line options: each refuses what the option cannot mean.

argparse calls them on the option's text; a refusal is argparse's one-line usage error
(exit status 2) that names the option, the value and the range. NaN, ±inf and values
outside the range never reach a computation (issue: ``--hdi-prob 0`` or ``--a-fixed nan``
must not give numbers with exit 0). Stdlib only: cheap to import from every CLI.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import re
from collections.abc import Callable

#: Seeds of NumPy's generators are non-negative integers below 2**63 (``SeedSequence``).
SEED_MAX = 2**63 - 1


def _number(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return v


def real(
    low: float, high: float = math.inf, *, open_low: bool = False, open_high: bool = False
) -> Callable[[str], float]:
    """A finite number in [low, high] (``open_low``/``open_high``: the end excluded)."""
    lo, hi = ("(" if open_low else "["), (")" if open_high else "]")
    where = f"{lo}{low:g}, {high:g}{hi}" if math.isfinite(high) else f"{lo}{low:g}, ∞)"

    def parse(text: str) -> float:
        v = _number(text)
        below = v <= low if open_low else v < low
        above = v >= high if open_high else v > high
        if below or above:
            raise argparse.ArgumentTypeError(f"{text} is outside {where}")
        return v

    parse.__name__ = f"number in {where}"
    return parse


def integer(low: int, high: int = SEED_MAX) -> Callable[[str], int]:
    """A whole number in [low, high]."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(f"{text} is outside [{low}, {high}]")
        return v

    parse.__name__ = f"whole number in [{low}, {high}]"
    return parse


def zero_or(low: float, high: float = math.inf) -> Callable[[str], float]:
    """0 (the option off), or a finite number in [low, high]: a value between would mean
    nothing and overflow what it divides."""
    inner = real(low, high)

    def parse(text: str) -> float:
        v = _number(text)
        if v == 0.0:
            return 0.0
        try:
            return inner(text)
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(
                f"{text} is neither 0 nor in [{low:g}, {high:g}]"
            ) from None

    parse.__name__ = f"0 or a number in [{low:g}, {high:g}]"
    return parse


def date(text: str) -> _dt.date:
    """A calendar date written YYYY-MM-DD (``2027-13-45`` and ``banana`` are none)."""
    if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", text):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a date written YYYY-MM-DD (e.g. 2027-03-15)"
        )
    try:
        return _dt.date.fromisoformat(text)
    except ValueError as e:  # the form is right, the day is not: say which part
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a date written YYYY-MM-DD ({e})"
        ) from None


date.__name__ = "date YYYY-MM-DD"

#: Probabilities of an interval: 0 and 1 are not intervals.
probability = real(0.0, 1.0, open_low=True, open_high=True)
seed = integer(0)
positive = real(0.0, open_low=True)
non_negative = real(0.0)
count = integer(1, 10_000)


class Parser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line (``prog: error: …``, exit status
    2) pointing to ``--help``, not the usage block before it; its subparsers are the same."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")
