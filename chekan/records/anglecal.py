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
    # scale_part_y_arcsec: 0.2        (optional: the part of the Y table's U that is a
                                      scale error, see below; scale_part_x_arcsec likewise)
    axis,angle_arcsec,correction_arcsec,U_arcsec
    y,-18600,0.84,0.50
    …

A lab that knows how its angles' errors correlate may say so: ``scale_part_<axis>_arcsec``
is the part of U (k = 2, at the table's largest |angle|) that is a scale error,
proportional to the angle and common to every row; the rest of U is then independent from
angle to angle. Without it neither is assumed (:mod:`chekan.joint.angles` carries both
extremes).

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
SCALE_KEY = "scale_part_{axis}_arcsec"  # optional: the part of an axis's U that is a scale error


@dataclass(frozen=True)
class AxisTable:
    """One sensor's table: angles (arcsec, increasing), corrections and U (k = 2), and
    ``scale_U_arcsec``: where the lab states it, the part of U that is a scale error
    (k = 2 at the table's largest |angle|, proportional to the angle and common to all
    rows; the rest of U independent from angle to angle). None: not stated."""

    axis: str
    angle_arcsec: np.ndarray
    correction_arcsec: np.ndarray
    U_arcsec: np.ndarray
    scale_U_arcsec: float | None = None

    @property
    def max_angle_arcsec(self) -> float:
        """The table's largest |angle| (where ``scale_U_arcsec`` is given)."""
        return float(np.max(np.abs(self.angle_arcsec)))

    def scale_u_at(self, theta_arcsec: np.ndarray) -> np.ndarray:
        """Standard uncertainty of the stated scale part at angles ``theta_arcsec``:
        (U_s/2)·|θ|/θ_max (zero where no scale part is stated)."""
        s = 0.0 if self.scale_U_arcsec is None else self.scale_U_arcsec / 2.0
        return s * np.abs(np.asarray(theta_arcsec, dtype=float)) / self.max_angle_arcsec

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
        scale = {a: t.scale_U_arcsec for a, t in self.tables.items()}
        scale = {a: v for a, v in scale.items() if v is not None}
        if scale:  # the lab's statement of how its angles' errors correlate
            out["scale_U_arcsec"] = dict(sorted(scale.items()))
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
    tables = _with_scale_statements(tables, frame, p)
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


def _with_scale_statements(tables: dict[str, AxisTable], frame, p: Path) -> dict[str, AxisTable]:
    """The tables with the optional ``scale_part_<axis>_arcsec`` keys applied: the part of U
    (k = 2, at the table's largest |angle|) that is a scale error. It is a part of U, so
    at every row U ≥ U_s·|θ|/θ_max; errors name the file and the line."""
    out = dict(tables)
    for axis in AXES:
        key = SCALE_KEY.format(axis=axis)
        raw = frame.meta.get(key)
        if raw is None:
            continue
        line = frame.meta_lines.get(key)
        if axis not in tables:
            raise FormatError(p, line, f"{key} given, but the file has no {axis} rows")
        try:
            value = float(raw)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value >= 0.0):
            raise FormatError(p, line, f"{key}: expected arcsec ≥ 0, got {raw.strip()!r}")
        table = replace(tables[axis], scale_U_arcsec=value)
        need = 2.0 * table.scale_u_at(table.angle_arcsec)
        over = np.flatnonzero(need > table.U_arcsec * (1.0 + 1e-9) + 1e-12)
        if over.size:
            i = int(over[0])
            raise FormatError(
                p,
                line,
                f"{key} = {value:g}″ is not a part of U: at {table.angle_arcsec[i]:g}″ its "
                f"share {need[i]:.3g}″ exceeds that row's U {table.U_arcsec[i]:g}″",
            )
        out[axis] = table
    return out


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


def calibrated(record, option: str | Path | AngleCalibration | None, input_path=None):
    """``record`` with its angle calibration applied (:func:`calibration_for`,
    :func:`corrected`); unchanged without one, or where one is applied already."""
    if record.angle_calibration is not None:
        return record  # already applied
    cal = calibration_for(record, option, input_path)
    return record if cal is None else corrected(record, cal)
