"""Reader of legacy calibration protocol tables, format ``chekan-protocol/1``.

The contract is ``docs/specs/legacy-protocol.md``: the framing of
``chekan-record/1`` (``# key: value`` metadata, a header line, CSV rows) with
one row per tilt angle: the angle, the reference increment ``da_ref_mgal`` and
the measured increments ``dg_rR_sS`` of system S in round R, each with its
scale factor ``b_rR_sS`` in the metadata.

Values are kept in the protocol's own sign convention (increments of a tilt
counted positive); mapping onto the record's convention is the analysis' job.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from os import PathLike

import numpy as np

from chekan.errors import FormatError
from chekan.physics.units import ARCSEC_PER_RAD, one_minus_cos, parse_angle_deg
from chekan.records.framing import (
    check_gravity_mgal,
    count_problem,
    data_block,
    meta_float,
    read_frame,
    warn_incomplete,
)

FORMAT = "chekan-protocol/1"
_DG_RE = re.compile(r"dg_r(\d+)_s(\d+)")
_NUM_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


@dataclass(eq=False)
class Protocol:
    """A legacy protocol table in memory (protocol sign convention: increments positive)."""

    meta: dict[str, str]
    serial: str
    a_mgal_per_pix2: float
    g_local_mgal: float | None
    angle_deg: np.ndarray  # (n,) magnitudes, decimal degrees
    angle_text: list[str]  # as written
    da_ref_mgal: np.ndarray  # (n,)
    rounds: tuple[int, ...]
    systems: tuple[int, ...]
    dg_mgal: np.ndarray  # (len(rounds), len(systems), n), NaN where empty or absent
    b_mgal_per_pix: np.ndarray  # (len(rounds), len(systems)), NaN where the column is absent
    path: str | None = None
    warnings: list[str] = field(default_factory=list)
    meta_lines: dict[str, int] = field(default_factory=dict, repr=False, compare=False)

    @property
    def n(self) -> int:
        """Number of angles (rows)."""
        return len(self.angle_deg)

    def g_fitted_mgal(self) -> float:
        """Least-squares g reproducing ``da_ref = g (1 − cos θ)``, 1 − cos θ as 2 sin²(θ/2)."""
        x = one_minus_cos(np.deg2rad(self.angle_deg))
        sxx = float(np.dot(x, x))
        if sxx == 0.0:
            raise ValueError(f"{self.path}: cannot fit g, every angle is zero")
        return float(np.dot(x, self.da_ref_mgal)) / sxx

    def g_local_or_fitted(self) -> float:
        """``g_local_mgal`` from the metadata, else :meth:`g_fitted_mgal`."""
        if self.g_local_mgal is not None:
            return self.g_local_mgal
        return self.g_fitted_mgal()


class _RowError(Exception):
    """Problem with one data row (message is the problem)."""


def _number(name: str, text: str, *, required: bool) -> float:
    """Parse one numeric field; empty gives NaN unless ``required``."""
    s = text.strip(" \t")
    if not s:
        if required:
            raise _RowError(f"field {name} is empty")
        return math.nan
    if not _NUM_RE.fullmatch(s):
        raise _RowError(f"field {name}: {s!r} is not a number")
    v = float(s)
    if not math.isfinite(v):
        raise _RowError(f"field {name}: {s!r} is not a finite number")
    return v


def _parse_row(
    raw: bytes, ncols: int, i_angle: int, i_da: int, dg_cols: list[tuple[str, int]]
) -> tuple[float, str, float, list[float]]:
    """One row -> (angle_deg magnitude, angle text, da_ref, dg values in ``dg_cols`` order)."""
    try:
        line = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise _RowError(
            f"not UTF-8 text (byte 0x{raw[e.start]:02x} at column {e.start + 1})"
        ) from None
    parts = line.split(",")
    if len(parts) != ncols:
        raise _RowError(count_problem(raw, len(parts), ncols))
    text = parts[i_angle].strip(" \t")
    if not text:
        raise _RowError("field angle is empty")
    try:
        angle = abs(parse_angle_deg(text))
    except ValueError as e:
        raise _RowError(f"field angle: {e}") from None
    if not math.isfinite(angle):
        raise _RowError(f"field angle: {text!r} is not a finite angle")
    da = _number("da_ref_mgal", parts[i_da], required=True)
    dg = [_number(name, parts[j], required=False) for name, j in dg_cols]
    return angle, text, da, dg


#: How far a row's ``da_ref_mgal`` may lie from g(1 − cos θ): the change of g(1 − cos θ)
#: over 1″ of angle, plus the table's rounding of the increment (0.01 mGal).
CONSISTENCY_ARCSEC = 1.0
ROUNDING_MGAL = 0.01


def check_reference_increments(
    angle_deg: np.ndarray,
    da_ref_mgal: np.ndarray,
    path: str | PathLike,
    lines: list[int],
    angle_text: list[str],
) -> float:
    """The g (mGal) that the table's increments imply, after checking every row against
    ``da_ref = g (1 − cos θ)``: g is the median of the rows' own ``da_ref / (1 − cos θ)`` (one
    wrong row cannot move it) and must be the Earth's; a row farther from it than 1″ of angle
    (a mistyped angle or increment) is a :class:`FormatError` at its line."""
    theta = np.deg2rad(angle_deg)
    x = one_minus_cos(theta)
    tilted = x > 0
    if not tilted.any():
        raise FormatError(path, None, "every angle is zero: no reference increment")
    g = float(np.median(da_ref_mgal[tilted] / x[tilted]))
    check_gravity_mgal(g, path, None, "the g implied by da_ref_mgal (median of the rows)")
    tol = g * np.sin(theta) * CONSISTENCY_ARCSEC / ARCSEC_PER_RAD + ROUNDING_MGAL
    off = np.abs(da_ref_mgal - g * x) > tol
    if off.any():
        i = int(np.argmax(off))
        raise FormatError(
            path,
            lines[i],
            f"da_ref_mgal {da_ref_mgal[i]:.2f} does not match g(1 − cos θ) = "
            f"{g * x[i]:.2f} mGal for angle {angle_text[i]} (g = {g:.2f} mGal from the other "
            f"rows; {int(off.sum())} row(s) off by more than 1″ of angle): a mistyped angle or "
            "increment?",
        )
    return g


def read_protocol(path: str | PathLike) -> Protocol:
    """Read a ``chekan-protocol/1`` file; malformed input raises :class:`FormatError`.

    An incomplete final line is skipped with an ``IncompleteLineWarning`` (also
    listed in ``Protocol.warnings``), as for records.
    """
    with open(path, "rb") as f:
        raw = f.read()
    fr = read_frame(raw, path, FORMAT)
    meta, lines_of = fr.meta, fr.meta_lines
    for key in ("serial", "a_mgal_per_pix2"):
        if key not in meta:
            raise FormatError(path, None, f"missing required metadata key {key!r}")
    serial = meta["serial"].strip()
    if not serial:
        raise FormatError(path, lines_of["serial"], "metadata serial is empty")
    a = meta_float(meta, lines_of, path, "a_mgal_per_pix2")
    g = meta_float(meta, lines_of, path, "g_local_mgal")
    assert a is not None
    if g is not None:
        check_gravity_mgal(g, path, lines_of.get("g_local_mgal"), "metadata g_local_mgal")

    index = {c: i for i, c in enumerate(fr.columns)}
    for c in ("angle", "da_ref_mgal"):
        if c not in index:
            raise FormatError(path, fr.header_line, f"missing required column {c!r}")
    cells: dict[tuple[int, int], tuple[str, int]] = {}
    for name, j in index.items():
        m = _DG_RE.fullmatch(name)
        if m is None:
            continue
        try:  # int() refuses more than 4300 digits; leading zeros do not count
            cell = (int(m.group(1).lstrip("0") or "0"), int(m.group(2).lstrip("0") or "0"))
        except ValueError:
            raise FormatError(
                path, fr.header_line, f"column {name!r}: round or system number is too large"
            ) from None
        if cell in cells:
            raise FormatError(
                path,
                fr.header_line,
                f"columns {cells[cell][0]!r} and {name!r} are the same round and system",
            )
        cells[cell] = (name, j)
    if not cells:
        raise FormatError(
            path, fr.header_line, "no measured-increment columns (dg_rR_sS, e.g. dg_r1_s1)"
        )
    rounds = tuple(sorted({r for r, _ in cells}))
    systems = tuple(sorted({s for _, s in cells}))
    b = np.full((len(rounds), len(systems)), np.nan)
    for (r, s), (name, _) in cells.items():
        bkey = "b" + name[2:]
        if bkey not in meta:
            raise FormatError(
                path, fr.header_line, f"column {name!r} has no metadata key {bkey!r} (its b)"
            )
        b_rs = meta_float(meta, lines_of, path, bkey)
        assert b_rs is not None
        if b_rs <= 0.0:
            raise FormatError(
                path, lines_of.get(bkey), f"metadata {bkey}: a scale factor must be positive"
            )
        b[rounds.index(r), systems.index(s)] = b_rs

    dg_cols = [(cells[k][0], cells[k][1]) for k in sorted(cells)]
    block, final_nl = data_block(fr.data)
    rows = block.split(b"\n")[:-1]
    first = fr.header_line + 1
    notes: list[str] = []
    if rows and b"\0" in rows[-1]:
        warn_incomplete(path, first + len(rows) - 1, "NUL bytes", notes, stacklevel=3)
        rows.pop()
        final_nl = True
    parsed = []
    row_lines = []
    for i, row in enumerate(rows):
        try:
            parsed.append(
                _parse_row(row, len(fr.columns), index["angle"], index["da_ref_mgal"], dg_cols)
            )
            row_lines.append(first + i)
        except _RowError as e:
            if i == len(rows) - 1 and not final_nl:
                warn_incomplete(path, first + i, str(e), notes, stacklevel=3)
                break
            raise FormatError(path, first + i, str(e)) from None
    if not parsed:
        raise FormatError(path, None, "protocol has no data rows")

    angle_deg = np.array([p[0] for p in parsed])
    da_ref = np.array([p[2] for p in parsed])
    check_reference_increments(angle_deg, da_ref, path, row_lines, [p[1] for p in parsed])
    n = len(parsed)
    dg = np.full((len(rounds), len(systems), n), np.nan)
    for k, (r, s) in enumerate(sorted(cells)):
        dg[rounds.index(r), systems.index(s)] = [p[3][k] for p in parsed]
    return Protocol(
        meta=meta,
        serial=serial,
        a_mgal_per_pix2=a,
        g_local_mgal=g,
        angle_deg=angle_deg,
        angle_text=[p[1] for p in parsed],
        da_ref_mgal=da_ref,
        rounds=rounds,
        systems=systems,
        dg_mgal=dg,
        b_mgal_per_pix=b,
        path=str(path),
        warnings=notes,
        meta_lines=lines_of,
    )
