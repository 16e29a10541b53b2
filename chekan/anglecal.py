"""The platform's own angle calibration: a correction table per angle sensor.

A lab can calibrate the platform's angle sensors against a precision tilt table or an
autocollimator. The result is, per axis, the correction c(θ) to add to the sensor's
reading (true angle = reading + c, GUM 3.2.3) and its expanded uncertainty U(θ) at k = 2.
File format ``chekan-angle-calibration/1`` (framed like a record: ``# key: value``
lines, one column header, CSV rows)::

    # format: chekan-angle-calibration/1
    # id: AC-2026-017                 (required: the calibration's identifier)
    # date: 2026-10-02                (required: ISO 8601 date of the calibration)
    # platform_serial: 1234           (optional; checked against the record's)
    # laboratory: …                   (optional, free text)
    axis,angle_arcsec,correction_arcsec,U_arcsec
    y,-18600,0.84,0.50
    …

Between two angles of a table the correction and U are interpolated linearly. Nothing is
extrapolated: an angle more than ``END_TOLERANCE_ARCSEC`` beyond a table's ends is an
error; within it the end value holds (a hold's reading scatters by a few arcsec about
its commanded angle, and a table is naturally given at the commanded angles).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import itertools
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from chekan.errors import ChekanError, FormatError
from chekan.records.framing import decode_line, read_frame

FORMAT = "chekan-angle-calibration/1"
COLUMNS = ("axis", "angle_arcsec", "correction_arcsec", "U_arcsec")
AXES = ("x", "y")
END_TOLERANCE_ARCSEC = 30.0  # = chekan.joint.angles.GROUP_ARCSEC: one commanded angle
HEADER_KEY = "angle_calibration"  # record header: the table's file (relative to the record)


@dataclass(frozen=True)
class AxisTable:
    """One sensor's table: angles (arcsec, increasing), corrections and U (k = 2)."""

    axis: str
    angle_arcsec: np.ndarray
    correction_arcsec: np.ndarray
    U_arcsec: np.ndarray

    @property
    def span_arcsec(self) -> tuple[float, float]:
        return float(self.angle_arcsec[0]), float(self.angle_arcsec[-1])

    def covers(self, theta_arcsec: np.ndarray) -> np.ndarray:
        """Which angles lie inside the table (its ends ± ``END_TOLERANCE_ARCSEC``)."""
        lo, hi = self.span_arcsec
        th = np.asarray(theta_arcsec, dtype=float)
        return (th >= lo - END_TOLERANCE_ARCSEC) & (th <= hi + END_TOLERANCE_ARCSEC)

    def correction_at(self, theta_arcsec: np.ndarray) -> np.ndarray:
        """c(θ), arcsec, interpolated linearly (call :meth:`covers` first)."""
        return np.interp(theta_arcsec, self.angle_arcsec, self.correction_arcsec)

    def u_at(self, theta_arcsec: np.ndarray) -> np.ndarray:
        """Standard uncertainty U(θ)/2 of the corrected angle, arcsec."""
        return np.interp(theta_arcsec, self.angle_arcsec, self.U_arcsec) / 2.0


@dataclass(frozen=True)
class AngleCalibration:
    """A platform angle calibration: identifier, date, tables per axis, the file read."""

    id: str
    date: str
    tables: dict[str, AxisTable]
    path: str = "<memory>"
    sha256: str | None = None
    meta: dict[str, str] = field(default_factory=dict)

    def table(self, axis: str) -> AxisTable | None:
        return self.tables.get(axis)

    def entry(self) -> dict:
        """What the result states of it (the traceability of the angle)."""
        out: dict = {
            "id": self.id,
            "date": self.date,
            "file": self.path,
            "axes": sorted(self.tables),
        }
        if self.sha256:
            out["sha256"] = self.sha256
        for key in ("laboratory", "platform_serial", "method"):
            if self.meta.get(key):
                out[key] = self.meta[key]
        return out


def read_angle_calibration(path: str | Path) -> AngleCalibration:
    """Read and check a correction table; errors name the file and the line (exit 2)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise ChekanError(f"{p}: cannot read the angle calibration: {e.strerror or e}") from None
    frame = read_frame(raw, p, FORMAT)
    for key in ("id", "date"):
        if not frame.meta.get(key, "").strip():
            raise FormatError(p, None, f"missing required metadata key {key!r}")
    date = frame.meta["date"].strip()
    try:
        dt.date.fromisoformat(date)
    except ValueError:
        raise FormatError(p, frame.meta_lines["date"], f"date {date!r} is not YYYY-MM-DD") from None
    missing = [c for c in COLUMNS if c not in frame.columns]
    if missing:
        raise FormatError(p, frame.header_line, f"missing column(s) {', '.join(missing)}")
    rows = _rows(frame, p)
    tables = {axis: _table(axis, rows[axis], p) for axis in AXES if rows[axis]}
    if not tables:
        raise FormatError(p, None, "no rows: a table needs at least two angles of an axis")
    return AngleCalibration(
        id=frame.meta["id"].strip(),
        date=date,
        tables=tables,
        path=str(p),
        sha256=hashlib.sha256(raw).hexdigest(),
        meta={k: v.strip() for k, v in frame.meta.items()},
    )


def _rows(frame, p: Path) -> dict[str, list[tuple[int, float, float, float]]]:
    """The data rows by axis: (line, angle, correction, U)."""
    col = {c: i for i, c in enumerate(frame.columns)}
    out: dict[str, list[tuple[int, float, float, float]]] = {a: [] for a in AXES}
    for k, line in enumerate(frame.data.split(b"\n")):
        lineno = frame.header_line + 1 + k
        text = decode_line(line.rstrip(b"\r"), p, lineno)
        if not text.strip():
            continue
        fields = [f.strip() for f in text.split(",")]
        if len(fields) != len(frame.columns):
            raise FormatError(
                p, lineno, f"{len(fields)} fields, the header has {len(frame.columns)}"
            )
        axis = fields[col["axis"]].lower()
        if axis not in AXES:
            raise FormatError(p, lineno, f"axis {fields[col['axis']]!r}: expected x or y")
        nums = []
        for name in COLUMNS[1:]:
            try:
                v = float(fields[col[name]])
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise FormatError(p, lineno, f"{name}: not a finite number: {fields[col[name]]!r}")
            nums.append(v)
        angle, corr, U = nums
        if U < 0:
            raise FormatError(p, lineno, f"U_arcsec must be ≥ 0 (an uncertainty), got {U:g}")
        if abs(angle) > 6 * 3600 or abs(corr) > 600:
            raise FormatError(
                p, lineno, f"angle {angle:g}″ or correction {corr:g}″ outside any platform's range"
            )
        out[axis].append((lineno, angle, corr, U))
    return out


def _table(axis: str, rows: list[tuple[int, float, float, float]], p: Path) -> AxisTable:
    if len(rows) < 2:
        raise FormatError(p, rows[0][0], f"axis {axis}: at least two angles are needed")
    rows = sorted(rows, key=lambda r: r[1])
    for (l0, a0, *_), (l1, a1, *_) in itertools.pairwise(rows):
        if a1 == a0:
            raise FormatError(p, l1, f"axis {axis}: angle {a1:g}″ given twice (line {l0})")
    arr = np.array([r[1:] for r in rows], dtype=float)
    return AxisTable(axis, arr[:, 0], arr[:, 1], arr[:, 2])


def corrected(record, cal: AngleCalibration):
    """A new record whose angle columns carry the corrections (θ + c(θ)), and which names
    ``cal``; an angle the table does not cover is an error naming both files."""
    cols = {}
    for axis in AXES:
        name = f"tilt_{axis}_arcsec"
        theta = getattr(record, name)
        table = cal.table(axis)
        if table is None:
            if _tilted(record, theta):
                raise ChekanError(
                    f"{cal.path}: no table for the {axis.upper()} sensor, but "
                    f"{record.path or 'the record'} tilts about {axis.upper()}"
                )
            continue
        finite = np.isfinite(theta)
        bad = finite & ~table.covers(theta)
        if bad.any():
            i = int(np.argmax(bad))
            lo, hi = table.span_arcsec
            raise ChekanError(
                f"{cal.path}: axis {axis} covers {lo:g}…{hi:g}″, but {record.path or 'the record'}"
                f" reads {theta[i]:g}″ (t = {record.t_s[i]:g} s): nothing is extrapolated"
            )
        cols[name] = np.where(
            finite, theta + table.correction_at(np.where(finite, theta, 0.0)), theta
        )
    serial = cal.meta.get("platform_serial", "").strip()
    rec_serial = record.meta.get("platform_serial", "").strip()
    if serial and rec_serial and serial != rec_serial:
        raise ChekanError(
            f"{cal.path}: calibrates platform {serial}, {record.path or 'the record'} "
            f"was taken on platform {rec_serial}"
        )
    return replace(record, angle_calibration=cal, warnings=list(record.warnings), **cols)


def _tilted(record, theta: np.ndarray) -> bool:
    """Whether the record holds steps away from level about this axis (> 30″)."""
    held = (record.step >= 0) & np.isfinite(theta)
    return bool(held.any() and np.max(np.abs(theta[held])) > END_TOLERANCE_ARCSEC)


def calibration_for(record, option: str | Path | AngleCalibration | None, input_path=None):
    """The angle calibration a record is to use: the option (a path or a table), else the
    record header's ``angle_calibration`` (a path relative to the record's folder), else
    None."""
    if isinstance(option, AngleCalibration):
        return option
    if option is not None:
        return read_angle_calibration(option)
    name = record.meta.get(HEADER_KEY, "").strip()
    if not name:
        return None
    origin = input_path or record.path
    p = Path(name)
    if not p.is_absolute():
        p = (Path(origin).parent if origin else Path()) / p
    if not p.is_file():
        line = record.meta_lines.get(HEADER_KEY)
        where = f"{origin}:{line}" if origin and line else str(origin or "the record")
        raise ChekanError(f"{where}: {HEADER_KEY}: no such file {str(p)!r}")
    return read_angle_calibration(p)
