"""The :class:`Record` type and :func:`read_record`, the reader of ``chekan-record/1``.

The contract is ``docs/specs/record-format.md``: ``# key: value`` metadata
lines, one comma-separated header line, then one data row per sensor sample.

Reading is fast: the data block is parsed by a vectorised NumPy parser
(33 000 rows in a few tens of milliseconds). Whenever that parser meets
anything it does not handle (a malformed row, exponent notation, blanks
around numbers, …) the whole block is re-read by a line-by-line parser that
either accepts it or reports the first bad line precisely, so the fast path
never changes what is accepted (:mod:`chekan.records.parse`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

import numpy as np

from chekan.errors import FormatError
from chekan.records.framing import (
    PathArg,
    check_gravity_mgal,
    data_block,
    meta_float,
    read_bytes,
    read_frame,
)
from chekan.records.parse import parse_data

FORMAT = "chekan-record/1"
DEFAULT_COLUMNS: tuple[str, ...] = (
    "t_s",
    "m1_pix",
    "m2_pix",
    "tilt_x_arcsec",
    "tilt_y_arcsec",
    "step",
    "temp_c",
)
REQUIRED_COLUMNS: tuple[str, ...] = DEFAULT_COLUMNS[:6]
REQUIRED_KEYS: tuple[str, ...] = ("format", "serial", "g_local_mgal")
#: the per-sample columns of a Record, one value per row
COLUMNS: tuple[str, ...] = (
    "t_s",
    "m1_pix",
    "m2_pix",
    "tilt_x_arcsec",
    "tilt_y_arcsec",
    "step",
    "temp_c",
)


@dataclass(eq=False)
class Record:
    """A calibration record in memory (one row per sensor sample)."""

    meta: dict[str, str]
    t_s: np.ndarray
    m1_pix: np.ndarray
    m2_pix: np.ndarray
    tilt_x_arcsec: np.ndarray
    tilt_y_arcsec: np.ndarray
    step: np.ndarray
    temp_c: np.ndarray | None = None
    path: str | None = None
    warnings: list[str] = field(default_factory=list)
    meta_lines: dict[str, int] = field(default_factory=dict, repr=False, compare=False)
    # the platform angle calibration applied to the tilt columns (chekan.records.anglecal), if any
    angle_calibration: Any = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Coerce the arrays (float64, step int64) and check they have one length."""
        self.meta = {str(k): str(v) for k, v in self.meta.items()}
        for name in ("t_s", "m1_pix", "m2_pix", "tilt_x_arcsec", "tilt_y_arcsec"):
            setattr(self, name, np.asarray(getattr(self, name), dtype=np.float64).reshape(-1))
        step = np.asarray(self.step)
        if step.dtype.kind == "f":
            step = np.where(np.isnan(step), -1, step)
        self.step = step.astype(np.int64).reshape(-1)
        if self.temp_c is not None:
            self.temp_c = np.asarray(self.temp_c, dtype=np.float64).reshape(-1)
        n = len(self.t_s)
        for name in COLUMNS[1:]:
            a = getattr(self, name)
            if a is not None and len(a) != n:
                raise ValueError(f"Record.{name} has {len(a)} values, t_s has {n}")

    def _float(self, key: str, default: float | None = None) -> float | None:
        """Metadata ``key`` as a float, validated; errors name the metadata line."""
        return meta_float(self.meta, self.meta_lines, self.path, key, default)

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.t_s)

    def rows(self, keep: np.ndarray) -> Record:
        """A new record of the rows where ``keep`` (a boolean mask) is True, the same
        header: the record as it would be had the others been lost."""
        cols = {k: getattr(self, k) for k in COLUMNS}
        return dataclasses.replace(self, **{k: v[keep] for k, v in cols.items() if v is not None})

    @property
    def serial(self) -> str:
        """Gravimeter serial number (required)."""
        s = self.meta.get("serial", "").strip()
        if not s:
            raise FormatError(self.path, self.meta_lines.get("serial"), "no serial number")
        return s

    @property
    def g_local_mgal(self) -> float:
        """Absolute gravity at the site, mGal (required)."""
        v = self._float("g_local_mgal")
        if v is None:
            raise FormatError(self.path, None, "missing required metadata key 'g_local_mgal'")
        line = self.meta_lines.get("g_local_mgal")
        return check_gravity_mgal(v, self.path, line, "metadata g_local_mgal")

    @property
    def sample_rate_hz(self) -> float:
        """Nominal sensor rate, Hz (default 1)."""
        v = self._float("sample_rate_hz", 1.0)
        assert v is not None
        if v <= 0:
            raise FormatError(
                self.path, self.meta_lines.get("sample_rate_hz"), "sample_rate_hz must be > 0"
            )
        return v

    @property
    def ccd_center_pix(self) -> float:
        """CCD centre reading m0 of both systems, pixels (default 1024)."""
        v = self._float("ccd_center_pix", 1024.0)
        assert v is not None
        return v

    @property
    def ccd_range_pix(self) -> tuple[float, float]:
        """First and last usable pixel (default ``(0, 2048)``); written ``0 2048``."""
        if "ccd_range_pix" not in self.meta:
            return (0.0, 2048.0)
        text = self.meta["ccd_range_pix"]
        parts = text.replace(",", " ").split()
        try:
            lo, hi = (float(p) for p in parts)
        except ValueError:
            lo = hi = math.nan
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise FormatError(
                self.path,
                self.meta_lines.get("ccd_range_pix"),
                f"metadata ccd_range_pix: {text!r} is not two increasing numbers (e.g. '0 2048')",
            )
        return (lo, hi)

    @property
    def b_prior(self) -> tuple[float | None, float | None]:
        """Scale factors of the previous calibration ``(b1_prior, b2_prior)``, mGal/pix."""
        return (self._float("b1_prior"), self._float("b2_prior"))

    @property
    def started(self) -> str | None:
        """ISO 8601 UTC time of the first sample, as written (validated), or ``None``."""
        if "started" not in self.meta:
            return None
        s = self.meta["started"].strip()
        try:
            datetime.fromisoformat(s)
        except ValueError:
            raise FormatError(
                self.path,
                self.meta_lines.get("started"),
                f"metadata started: {s!r} is not ISO 8601",
            ) from None
        return s

    def columns(self) -> tuple[str, ...]:
        """The columns this record holds (``temp_c`` only when present)."""
        return DEFAULT_COLUMNS if self.temp_c is not None else REQUIRED_COLUMNS


# --------------------------------------------------------------------------- reading


def read_record(path: PathArg, *, max_rows: int | None = None) -> Record:
    """Read a ``chekan-record/1`` file; malformed input raises :class:`FormatError`.

    ``max_rows`` reads only the first rows (e.g. ``0`` for the metadata alone).
    An incomplete final line is skipped with an :class:`IncompleteLineWarning`
    (also listed in ``Record.warnings``).
    """
    raw = read_bytes(path, max_rows)
    fr = read_frame(raw, path, FORMAT)
    for key in REQUIRED_KEYS:
        if key not in fr.meta:
            raise FormatError(path, None, f"missing required metadata key {key!r}")
    if not fr.meta["serial"].strip():
        raise FormatError(path, fr.meta_lines["serial"], "metadata serial is empty")
    g = meta_float(fr.meta, fr.meta_lines, path, "g_local_mgal")
    assert g is not None
    check_gravity_mgal(g, path, fr.meta_lines.get("g_local_mgal"), "metadata g_local_mgal")
    index = {c: i for i, c in enumerate(fr.columns)}
    for c in REQUIRED_COLUMNS:
        if c not in index:
            raise FormatError(path, fr.header_line, f"missing required column {c!r}")
    want = {c: index[c] for c in DEFAULT_COLUMNS if c in index}
    block, final_nl = data_block(fr.data)
    vals, notes = parse_data(block, final_nl, fr.header_line + 1, len(fr.columns), want, path)
    check_magnitudes(vals, fr.header_line + 1, path)
    return Record(
        meta=fr.meta,
        t_s=vals["t_s"],
        m1_pix=vals["m1_pix"],
        m2_pix=vals["m2_pix"],
        tilt_x_arcsec=vals["tilt_x_arcsec"],
        tilt_y_arcsec=vals["tilt_y_arcsec"],
        step=vals["step"],
        temp_c=vals.get("temp_c"),
        path=str(path),
        warnings=notes,
        meta_lines=fr.meta_lines,
    )


#: What a reading of each column can be at most, in magnitude: beyond it a value is no
#: measurement (the CCD has 2048 pixels, a platform tilts by degrees, a record lasts days).
MAX_MAGNITUDE = {
    "t_s": 1e8,
    "m1_pix": 1e5,
    "m2_pix": 1e5,
    "tilt_x_arcsec": 648_000.0,
    "tilt_y_arcsec": 648_000.0,
    "temp_c": 1e3,
}


def check_magnitudes(vals: dict[str, np.ndarray], first_line: int, path: PathArg) -> None:
    """A :class:`FormatError` at the first data line holding a value beyond
    :data:`MAX_MAGNITUDE` (such as 1e308, which no estimator can use)."""
    for col, bound in MAX_MAGNITUDE.items():
        v = vals.get(col)
        if v is None:
            continue
        bad = np.abs(v) > bound  # NaN (an empty field) compares False
        if bad.any():
            i = int(np.argmax(bad))
            raise FormatError(
                path,
                first_line + i,
                f"field {col}: {v[i]:g} is not a possible value (|{col}| ≤ {bound:g})",
            )


def synthetic_record(n: int = 33_000, seed: int = 0) -> Record:
    """A synthetic record of ``n`` samples at 1 Hz (36 steps of 900 s, 300 s moving)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.float64)
    step = np.where(t % 900 < 30, -1, t // 900).astype(np.int64)
    m1 = 1031.0 + rng.normal(0, 0.01, n)
    m1[::997] = np.nan
    meta = {"serial": "46", "g_local_mgal": "981922.05", "sample_rate_hz": "1"}
    return Record(
        meta=meta,
        t_s=t,
        m1_pix=m1,
        m2_pix=1012.9 + rng.normal(0, 0.01, n),
        tilt_x_arcsec=rng.normal(0, 0.5, n),
        tilt_y_arcsec=rng.normal(0, 0.5, n),
        step=step,
        temp_c=45.0 + rng.normal(0, 0.002, n),
    )
