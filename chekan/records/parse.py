"""Parsers of the data block of a record: a vectorised fast path and a line-by-line one.

The fast path (:func:`fast_block`) parses plain decimals with NumPy and gives up
(``None``) on anything unusual; :func:`slow_block` then either accepts the block or
names the first bad row, so the fast path never changes what is accepted.
:func:`parse_data` applies both with the incomplete-final-line rule.
"""

from __future__ import annotations

import math
import re

import numpy as np

from chekan.errors import FormatError
from chekan.records.framing import PathArg, count_problem, last_line_start, warn_incomplete

_NUM_RE = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_INT_RE = re.compile(rb"\d+")
_POW10 = 10.0 ** np.arange(23)
_MAX_DIGITS = 15  # a decimal with at most 15 digits is parsed exactly by the fast path
_BLANKS = b" \t"


def fast_column(arr: np.ndarray, starts: np.ndarray, lens: np.ndarray, integer: bool):
    """Parse one column of fields vectorised; ``None`` if anything is unusual.

    Accepts ``-?digits[.digits]`` (``1.``, ``.5`` too) with at most 15 digits, which
    converts exactly (an integer below 2**53 divided by a power of ten is correctly
    rounded, as by ``float()``). ``integer``: digits only. Empty fields become NaN.
    Arrays are laid out (character position, row) so reductions run over rows.
    """
    n = len(starts)
    out = np.full(n, np.nan)
    width = int(lens.max()) if n else 0
    if width == 0:
        return out
    if width > _MAX_DIGITS + 2:
        return None
    j = np.arange(width)[:, None]
    valid = j < lens
    ch = arr.take(starts + j, mode="clip")  # (width, n)
    d = ch - np.uint8(48)
    is_digit = (d < 10) & valid
    is_dot = (ch == 46) & valid
    is_minus = (ch == 45) & valid
    if not np.array_equal(is_digit | is_dot | is_minus, valid):
        return None
    if integer and (is_dot.any() or is_minus.any()):
        return None
    if is_minus[1:].any():
        return None
    ndot = is_dot.sum(axis=0, dtype=np.int16)
    ndig = is_digit.sum(axis=0, dtype=np.int16)
    nonempty = lens > 0
    if ndot.max() > 1 or ndig.max() > _MAX_DIGITS or np.any(nonempty & (ndig == 0)):
        return None
    has_dot = ndot == 1
    p = np.argmax(is_dot, axis=0)
    # digits right of each digit = characters right of it, less the dot if it is right of it
    place = (lens - 1) - j
    place -= has_dot & (p > j)
    dd = np.where(is_digit, d, np.uint8(0))
    mant = (dd * _POW10[place]).sum(axis=0)  # exact: integers below 2**53
    frac = np.where(has_dot, lens - 1 - p, 0)
    val = mant / _POW10[frac]
    neg = is_minus[0]
    val[neg] = np.negative(val[neg])
    out[nonempty] = val[nonempty]
    return out


def fast_block(block: bytes, n: int, ncols: int, want: dict[str, int]):
    """Vectorised parse of an ``n``-row block; ``None`` unless every row is clean."""
    arr = np.frombuffer(block, dtype=np.uint8)
    sep = np.flatnonzero((arr == 44) | (arr == 10))
    if len(sep) != n * ncols:
        return None
    kinds = arr[sep].reshape(n, ncols)
    if not (np.all(kinds[:, -1] == 10) and np.all(kinds[:, :-1] == 44)):
        return None
    starts = np.empty(n * ncols, dtype=np.int64)
    starts[0] = 0
    starts[1:] = sep[:-1] + 1
    lens = np.ascontiguousarray((sep - starts).reshape(n, ncols).T)
    starts = np.ascontiguousarray(starts.reshape(n, ncols).T)
    out: dict[str, np.ndarray] = {}
    for name, j in want.items():
        col = fast_column(arr, starts[j], lens[j], integer=name == "step")
        if col is None:
            return None
        out[name] = col
    t = out["t_s"]
    if np.isnan(t).any() or np.any(t[1:] < t[:-1]):
        return None
    step = out["step"]
    out["step"] = np.where(np.isnan(step), -1, step).astype(np.int64)
    return out


def slow_block(block: bytes, ncols: int, want: dict[str, int]):
    """Line-by-line parse: ``(values, None)`` or ``(None, (row_index, problem))``."""
    lines = block.split(b"\n")[:-1]
    n = len(lines)
    vals = {name: np.full(n, np.nan) for name in want}
    step = np.full(n, -1, dtype=np.int64)
    prev_t: float | None = None
    items = list(want.items())
    for i, line in enumerate(lines):
        parts = line.split(b",")
        if len(parts) != ncols:
            return None, (i, count_problem(line, len(parts), ncols))
        for name, j in items:
            s = parts[j].strip(_BLANKS)
            if not s:
                if name == "t_s":
                    return None, (i, "field t_s is empty (every row needs a time)")
                continue
            text = s.decode("utf-8", "replace")
            if name == "step":
                if not _INT_RE.fullmatch(s):
                    return None, (i, f"field step: {text!r} is not a non-negative integer")
                if len(s.lstrip(b"0")) > _MAX_DIGITS:
                    return None, (i, f"field step: {text!r} is too large")
                step[i] = int(s.lstrip(b"0") or b"0")  # int() refuses > 4300 digits
                continue
            if not _NUM_RE.fullmatch(s):
                return None, (i, f"field {name}: {text!r} is not a number")
            v = float(s)
            if not math.isfinite(v):
                return None, (i, f"field {name}: {text!r} is not a finite number")
            vals[name][i] = v
        t = float(vals["t_s"][i])
        if prev_t is not None and t < prev_t:
            return None, (i, f"t_s goes backwards ({t!r} after {prev_t!r})")
        prev_t = t
    vals["step"] = step
    return vals, None


def parse_data(
    block: bytes,
    final_has_nl: bool,
    first_line: int,
    ncols: int,
    want: dict[str, int],
    path: PathArg,
) -> tuple[dict[str, np.ndarray], list[str]]:
    """Parse the data block with the final-line rule; errors name the physical line."""
    notes: list[str] = []
    n = block.count(b"\n")
    if n and b"\0" in block[last_line_start(block) :]:
        warn_incomplete(path, first_line + n - 1, "NUL bytes", notes)
        block = block[: last_line_start(block)]
        final_has_nl = True
        n -= 1
    for _ in range(2):
        vals = fast_block(block, n, ncols, want) if n else None
        if vals is None:
            vals, err = slow_block(block, ncols, want)
            if err is not None:
                i, problem = err
                if i == n - 1 and not final_has_nl:
                    warn_incomplete(path, first_line + i, problem, notes)
                    block = block[: last_line_start(block)]
                    final_has_nl = True
                    n -= 1
                    continue
                raise FormatError(path, first_line + i, problem)
        return vals, notes
    raise AssertionError("unreachable")  # pragma: no cover
