"""Reader and writer of calibration records, format ``chekan-record/1``.

The contract is ``shared/specs/record-format.md``: ``# key: value`` metadata
lines, one comma-separated header line, then one data row per sensor sample.

Reading is fast: the data block is parsed by a vectorised NumPy parser
(33 000 rows in a few tens of milliseconds). Whenever that parser meets
anything it does not handle (a malformed row, exponent notation, blanks
around numbers, …) the whole block is re-read by a line-by-line parser that
either accepts it or reports the first bad line precisely, so the fast path
never changes what is accepted.

Writing is either whole-file and atomic (:func:`write_record`) or streaming
and crash-safe (:class:`RecordWriter`): every line is flushed as it is
written, fsync'ed at most every ``fsync_interval_s``, and ``append=True``
resumes a record after a crash without losing anything (a torn last line is
saved aside).

Run ``python -m chekan.records [PATH]`` for a read-speed benchmark.
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from os import PathLike
from typing import Any, BinaryIO

import numpy as np

from chekan.errors import FormatError

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

_FLOAT_COLUMNS = ("t_s", "m1_pix", "m2_pix", "tilt_x_arcsec", "tilt_y_arcsec", "temp_c")
_META_RE = re.compile(r"# ([a-z0-9_]+): (.*)", re.DOTALL)
_KEY_RE = re.compile(r"[a-z0-9_]+")
_NUM_RE = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_INT_RE = re.compile(rb"\d+")
_BOM = b"\xef\xbb\xbf"
_POW10 = 10.0 ** np.arange(23)
_MAX_DIGITS = 15  # a decimal with at most 15 digits is parsed exactly by the fast path
_BLANKS = b" \t"

PathArg = str | PathLike


class IncompleteLineWarning(UserWarning):
    """An incomplete final line (interrupted write) was skipped."""


# --------------------------------------------------------------------------- framing


@dataclass
class _Frame:
    """Metadata, header and the raw data block of a framed CSV file."""

    meta: dict[str, str]
    meta_lines: dict[str, int]
    columns: list[str]
    header_line: int  # 1-based physical line of the header
    data: bytes  # everything after the header line's newline


def _decode(line: bytes, path: PathArg, lineno: int) -> str:
    """Decode one line as UTF-8; a FormatError names the line and the bad byte."""
    try:
        return line.decode("utf-8")
    except UnicodeDecodeError as e:
        raise FormatError(
            path, lineno, f"not UTF-8 text (byte 0x{line[e.start]:02x} at column {e.start + 1})"
        ) from None


def _read_frame(raw: bytes, path: PathArg, expected_format: str | None) -> _Frame:
    """Split ``raw`` into metadata, header and data; check the framing and ``format``.

    ``expected_format=None`` accepts any format value (used for sniffing).
    """
    if raw.startswith(_BOM):
        raw = raw[len(_BOM) :]
    if not raw.strip():
        raise FormatError(path, None, "empty file")
    meta: dict[str, str] = {}
    meta_lines: dict[str, int] = {}
    pos = 0
    lineno = 0
    while True:
        lineno += 1
        if pos >= len(raw):
            raise FormatError(path, lineno, "no column header line after the metadata")
        nl = raw.find(b"\n", pos)
        end = len(raw) if nl < 0 else nl
        line = raw[pos:end]
        if line.endswith(b"\r"):
            line = line[:-1]
        pos = len(raw) if nl < 0 else nl + 1
        if not line.startswith(b"#"):
            break
        text = _decode(line, path, lineno)
        m = _META_RE.fullmatch(text)
        if m is None:
            raise FormatError(
                path,
                lineno,
                f"malformed metadata line {text!r} (expected '# key: value', "
                "key of lower-case letters, digits and '_')",
            )
        key, value = m.group(1), m.group(2)
        if key in meta:
            raise FormatError(
                path, lineno, f"duplicate metadata key {key!r} (first on line {meta_lines[key]})"
            )
        meta[key] = value
        meta_lines[key] = lineno
        if key == "format" and expected_format is not None and value.strip() != expected_format:
            raise FormatError(
                path, lineno, f"format is {value.strip()!r}, expected {expected_format!r}"
            )
    if "format" not in meta:
        raise FormatError(
            path, None, "missing required metadata key 'format' (no '# format:' line)"
        )
    header = _decode(line, path, lineno)
    if not header.strip():
        raise FormatError(path, lineno, "expected the column header line, found an empty line")
    columns = [c.strip(" \t") for c in header.split(",")]
    seen: dict[str, int] = {}
    for i, c in enumerate(columns):
        if not c:
            raise FormatError(path, lineno, f"empty column name at position {i + 1}")
        if c in seen:
            raise FormatError(
                path, lineno, f"duplicate column {c!r} (positions {seen[c] + 1} and {i + 1})"
            )
        seen[c] = i
    return _Frame(meta, meta_lines, columns, lineno, raw[pos:])


def _data_block(data: bytes) -> tuple[bytes, bool]:
    """Normalise the data block: CRLF -> LF, drop trailing blank lines.

    Returns ``(block, final_has_newline)`` where ``block`` is empty or ends with ``\\n``
    (one is added to an unterminated final line) and holds one row per line.
    """
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n")
    end = len(data)
    while end > 0:
        if data[end - 1] == 0x0A:  # b"\n"
            start = data.rfind(b"\n", 0, end - 1) + 1
            last = data[start : end - 1]
        else:
            start = data.rfind(b"\n", 0, end) + 1
            last = data[start:end]
        if last.strip():
            break
        end = start
    content = data[:end]
    if not content:
        return b"", True
    if content.endswith(b"\n"):
        return content, True
    if content.endswith(b"\r"):  # torn between CR and LF
        content = content[:-1]
    return content + b"\n", False


def _last_line_start(block: bytes) -> int:
    """Offset of the last line of a non-empty ``\\n``-terminated block."""
    return block.rfind(b"\n", 0, len(block) - 1) + 1


def _incomplete(path: PathArg, lineno: int, why: str, sink: list[str], stacklevel: int = 4) -> None:
    """Record and emit the warning for a skipped incomplete final line."""
    msg = f"{path}:{lineno}: incomplete last line skipped ({why})"
    sink.append(msg)
    warnings.warn(msg, IncompleteLineWarning, stacklevel=stacklevel)


def _read_bytes(path: PathArg, max_rows: int | None) -> bytes:
    """The file's bytes; with ``max_rows`` only metadata, header and that many rows."""
    if max_rows is None:
        with open(path, "rb") as f:
            return f.read()
    parts: list[bytes] = []
    rows = -1  # the header line is not a row
    with open(path, "rb") as f:
        for line in f:
            parts.append(line)
            if line.startswith((b"#", _BOM + b"#")) and rows < 0:
                continue
            rows += 1
            if rows >= max_rows:
                break
    return b"".join(parts)


# --------------------------------------------------------------------------- data parsing


def _fast_column(arr: np.ndarray, starts: np.ndarray, lens: np.ndarray, integer: bool):
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


def _fast_block(block: bytes, n: int, ncols: int, want: dict[str, int]):
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
        col = _fast_column(arr, starts[j], lens[j], integer=name == "step")
        if col is None:
            return None
        out[name] = col
    t = out["t_s"]
    if np.isnan(t).any() or np.any(t[1:] < t[:-1]):
        return None
    step = out["step"]
    out["step"] = np.where(np.isnan(step), -1, step).astype(np.int64)
    return out


def _count_problem(line: bytes, k: int, ncols: int) -> str:
    """Message for a row with ``k`` fields where the header has ``ncols``."""
    what = f"row has {k} field{'s' if k != 1 else ''}, header has {ncols}"
    return f"empty line ({what})" if not line.strip() else what


def _slow_block(block: bytes, ncols: int, want: dict[str, int]):
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
            return None, (i, _count_problem(line, len(parts), ncols))
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
                step[i] = int(s)
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


def _parse_data(
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
    if n and b"\0" in block[_last_line_start(block) :]:
        _incomplete(path, first_line + n - 1, "NUL bytes", notes)
        block = block[: _last_line_start(block)]
        final_has_nl = True
        n -= 1
    for _ in range(2):
        vals = _fast_block(block, n, ncols, want) if n else None
        if vals is None:
            vals, err = _slow_block(block, ncols, want)
            if err is not None:
                i, problem = err
                if i == n - 1 and not final_has_nl:
                    _incomplete(path, first_line + i, problem, notes)
                    block = block[: _last_line_start(block)]
                    final_has_nl = True
                    n -= 1
                    continue
                raise FormatError(path, first_line + i, problem)
        return vals, notes
    raise AssertionError("unreachable")  # pragma: no cover


# --------------------------------------------------------------------------- Record


def _meta_float(
    meta: dict[str, str],
    lines: dict[str, int],
    path: PathArg | None,
    key: str,
    default: float | None = None,
) -> float | None:
    """Metadata value ``key`` as a finite float (``default`` if absent); errors name its line."""
    if key not in meta:
        return default
    try:
        v = float(meta[key].strip())
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise FormatError(
            path, lines.get(key), f"metadata {key}: {meta[key]!r} is not a finite number"
        )
    return v


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
        for name in ("m1_pix", "m2_pix", "tilt_x_arcsec", "tilt_y_arcsec", "step", "temp_c"):
            a = getattr(self, name)
            if a is not None and len(a) != n:
                raise ValueError(f"Record.{name} has {len(a)} values, t_s has {n}")

    def _float(self, key: str, default: float | None = None) -> float | None:
        """Metadata ``key`` as a float, validated; errors name the metadata line."""
        return _meta_float(self.meta, self.meta_lines, self.path, key, default)

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.t_s)

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
        return v

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
    raw = _read_bytes(path, max_rows)
    fr = _read_frame(raw, path, FORMAT)
    for key in REQUIRED_KEYS:
        if key not in fr.meta:
            raise FormatError(path, None, f"missing required metadata key {key!r}")
    if not fr.meta["serial"].strip():
        raise FormatError(path, fr.meta_lines["serial"], "metadata serial is empty")
    _meta_float(fr.meta, fr.meta_lines, path, "g_local_mgal")
    index = {c: i for i, c in enumerate(fr.columns)}
    for c in REQUIRED_COLUMNS:
        if c not in index:
            raise FormatError(path, fr.header_line, f"missing required column {c!r}")
    want = {c: index[c] for c in DEFAULT_COLUMNS if c in index}
    block, final_nl = _data_block(fr.data)
    vals, notes = _parse_data(block, final_nl, fr.header_line + 1, len(fr.columns), want, path)
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


# --------------------------------------------------------------------------- writing

_FMT = {"m1_pix": "%.4f", "m2_pix": "%.4f", "tilt_x_arcsec": "%.2f", "tilt_y_arcsec": "%.2f"}
_FMT["temp_c"] = "%.3f"


def _fmt_t(v: float) -> str:
    """Time: integer when integral, else up to 3 decimals."""
    s = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if s == "-0" else s


def _format_column(name: str, values: Any, n: int) -> list[str]:
    """Format one column's values as strings (empty for missing values)."""
    if values is None:
        if name == "t_s":
            raise ValueError("t_s is required")
        return [""] * n
    if name == "step":
        a = np.asarray(values, dtype=np.float64).reshape(-1)
        bad = a[np.isinf(a) | ((a >= 0) & (a != np.floor(a)))]
        if bad.size:
            raise ValueError(f"step must be an integer (negative or NaN: empty), not {bad[0]!r}")
        return [f"{v:.0f}" if v >= 0 else "" for v in np.nan_to_num(a, nan=-1.0).tolist()]
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(a) != n:
        raise ValueError(f"{name} has {len(a)} values, t_s has {n}")
    if np.isinf(a).any():
        raise ValueError(f"{name} has an infinite value")
    if name == "t_s":
        if np.isnan(a).any():
            raise ValueError("t_s must not be NaN")
        return [_fmt_t(v) for v in a.tolist()]
    fmt = _FMT[name]
    out = [fmt % v for v in a.tolist()]
    for i in np.flatnonzero(np.isnan(a)).tolist():
        out[i] = ""
    return out


def _format_rows(columns: Sequence[str], data: dict[str, Any]) -> tuple[bytes, int]:
    """Format whole columns into CSV lines; returns (bytes, row count)."""
    t = np.asarray(data["t_s"], dtype=np.float64).reshape(-1)
    n = len(t)
    cols = []
    for c in columns:
        v = data.get(c)
        if c == "step" and v is not None and len(np.asarray(v).reshape(-1)) != n:
            raise ValueError(f"step has {len(np.asarray(v).reshape(-1))} values, t_s has {n}")
        cols.append(_format_column(c, v, n))
    if n == 0:
        return b"", 0
    text = "\n".join(",".join(r) for r in zip(*cols, strict=True)) + "\n"
    return text.encode("ascii"), n


def _check_meta(meta: dict[str, str]) -> dict[str, str]:
    """Validate metadata for writing; returns it with ``format`` first."""
    out = {"format": FORMAT}
    for k, v in meta.items():
        k, v = str(k), str(v)
        if not _KEY_RE.fullmatch(k):
            raise ValueError(f"metadata key {k!r} must be lower case [a-z0-9_]+")
        if "\n" in v or "\r" in v:
            raise ValueError(f"metadata {k}: value must be one line, not {v!r}")
        if k == "format":
            if v.strip() != FORMAT:
                raise ValueError(f"metadata format must be {FORMAT!r}, not {v!r}")
            continue
        out[k] = v
    for k in ("serial", "g_local_mgal"):
        if not out.get(k, "").strip():
            raise ValueError(f"metadata key {k!r} is required")
    try:
        g = float(out["g_local_mgal"])
    except ValueError:
        g = math.nan
    if not math.isfinite(g):
        raise ValueError(f"metadata g_local_mgal must be a number, not {out['g_local_mgal']!r}")
    return out


def _fsync_dir(path: PathArg) -> None:
    """fsync the directory holding ``path`` so a new name survives a crash (POSIX)."""
    d = os.path.dirname(os.path.abspath(path))
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class RecordWriter:
    """Streaming, append-only, crash-safe writer of a ``chekan-record/1`` file.

    A new file gets the metadata (``format`` first) and the header at once. With
    ``append=True`` an existing record is continued after its last complete line;
    a torn final line is cut off and its bytes saved to ``<path>.torn-<n>``. ``meta``
    may then be ``None``; if given, each of its keys must be in the file with the
    same value (metadata cannot be added once data follow). The column order of an
    appended file is the file's own; its set of columns must equal ``columns``.

    Every line is flushed as written; ``os.fsync`` runs at most every
    ``fsync_interval_s`` (monotonic clock) and on :meth:`close`. Rows whose time
    would go backwards are refused (``ValueError``), so the file stays valid.
    An existing file is never overwritten unless ``overwrite=True``.
    """

    def __init__(
        self,
        path: PathArg,
        meta: dict[str, str] | None,
        *,
        append: bool = False,
        fsync_interval_s: float = 2.0,
        columns: Sequence[str] = DEFAULT_COLUMNS,
        overwrite: bool = False,
    ) -> None:
        self.path = str(path)
        self.fsync_interval_s = float(fsync_interval_s)
        cols = tuple(columns)
        unknown = [c for c in cols if c not in DEFAULT_COLUMNS]
        missing = [c for c in REQUIRED_COLUMNS if c not in cols]
        if unknown or missing or len(set(cols)) != len(cols):
            raise ValueError(
                f"columns must be distinct names from {DEFAULT_COLUMNS} including "
                f"{REQUIRED_COLUMNS}; got {cols}"
            )
        self.last_t: float | None = None
        self.torn_path: str | None = None
        self.n_written = 0
        self._f: BinaryIO | None = None
        exists = os.path.exists(self.path) and os.path.getsize(self.path) > 0
        if append and exists:
            self.columns = self._open_append(meta, cols)
        else:
            if meta is None:
                raise ValueError("meta is required to start a new record")
            header_meta = _check_meta(meta)
            self.columns = cols
            text = "".join(f"# {k}: {v}\n" for k, v in header_meta.items())
            text += ",".join(cols) + "\n"
            mode = "wb" if (overwrite or append) else "xb"
            self._f = open(self.path, mode)
            self._f.write(text.encode("utf-8"))
            self._f.flush()
            os.fsync(self._f.fileno())
            _fsync_dir(self.path)
        self._last_sync = time.monotonic()

    def _open_append(self, meta: dict[str, str] | None, cols: tuple[str, ...]) -> tuple[str, ...]:
        """Check an existing record, cut a torn last line aside, open it for appending."""
        with open(self.path, "rb") as f:
            raw = f.read()
        fr = _read_frame(raw, self.path, FORMAT)
        data_start = len(raw) - len(fr.data)
        if set(fr.columns) != set(cols):
            raise FormatError(
                self.path,
                fr.header_line,
                f"existing record has columns {tuple(fr.columns)}, the writer expects {cols}",
            )
        if meta is not None:
            for k, v in meta.items():
                if k not in fr.meta:
                    raise ValueError(f"{self.path}: metadata {k!r} is not in the existing record")
                if str(v) != fr.meta[k] and not (k == "format" and str(v).strip() == FORMAT):
                    raise ValueError(
                        f"{self.path}: metadata {k}={v!r} differs from the record's {fr.meta[k]!r}"
                    )
        cut = raw.rfind(b"\n") + 1
        cut = max(cut, data_start)
        torn = raw[cut:]
        if torn:
            k = 1
            while os.path.exists(f"{self.path}.torn-{k}"):
                k += 1
            self.torn_path = f"{self.path}.torn-{k}"
            with open(self.torn_path, "xb") as t:
                t.write(torn)
                t.flush()
                os.fsync(t.fileno())
            _fsync_dir(self.path)
        # last complete data line's time, for the monotonic guard
        body = raw[data_start:cut]
        lines = [ln for ln in body.split(b"\n") if ln.strip()]
        if lines:
            parts = lines[-1].rstrip(b"\r").split(b",")
            j = fr.columns.index("t_s")
            try:
                self.last_t = float(parts[j])
            except (IndexError, ValueError):
                self.last_t = None
        self._f = open(self.path, "r+b")
        self._f.truncate(cut)
        self._f.seek(cut)
        if cut == len(raw) and not raw.endswith(b"\n"):  # complete header, no newline yet
            self._f.write(b"\n")
        self._f.flush()
        os.fsync(self._f.fileno())
        return tuple(fr.columns)

    # -- writing

    def _emit(self, data: bytes) -> None:
        if self._f is None:
            raise ValueError(f"{self.path}: writer is closed")
        self._f.write(data)
        self._f.flush()
        now = time.monotonic()
        if now - self._last_sync >= self.fsync_interval_s:
            os.fsync(self._f.fileno())
            self._last_sync = now

    def write_row(
        self,
        t_s: float,
        m1_pix: float | None,
        m2_pix: float | None,
        tilt_x_arcsec: float | None,
        tilt_y_arcsec: float | None,
        step: int | None,
        temp_c: float | None = None,
    ) -> None:
        """Append one sample; ``None``/NaN write an empty field (``step`` < 0 too)."""

        def nz(v: Any) -> float:
            """None -> NaN."""
            return math.nan if v is None else float(v)

        self.write_rows(
            [t_s],
            [nz(m1_pix)],
            [nz(m2_pix)],
            [nz(tilt_x_arcsec)],
            [nz(tilt_y_arcsec)],
            [nz(step)],
            None if temp_c is None else [nz(temp_c)],
        )

    def write_rows(
        self,
        t_s: Iterable[float] | np.ndarray,
        m1_pix: Iterable[float] | np.ndarray,
        m2_pix: Iterable[float] | np.ndarray,
        tilt_x_arcsec: Iterable[float] | np.ndarray,
        tilt_y_arcsec: Iterable[float] | np.ndarray,
        step: Iterable[float] | np.ndarray,
        temp_c: Iterable[float] | np.ndarray | None = None,
    ) -> None:
        """Append many samples at once (vectorised formatting); NaN -> empty field."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        if len(t) == 0:
            return
        if np.isnan(t).any():
            raise ValueError("t_s must not be NaN")
        if np.any(t[1:] < t[:-1]) or (self.last_t is not None and t[0] < self.last_t):
            prev = self.last_t if self.last_t is not None and t[0] < self.last_t else None
            raise ValueError(f"{self.path}: t_s would go backwards (last written {prev})")
        data = {
            "t_s": t,
            "m1_pix": m1_pix,
            "m2_pix": m2_pix,
            "tilt_x_arcsec": tilt_x_arcsec,
            "tilt_y_arcsec": tilt_y_arcsec,
            "step": step,
            "temp_c": temp_c,
        }
        payload, n = _format_rows(self.columns, data)
        self._emit(payload)
        self.last_t = float(t[-1])
        self.n_written += n

    def flush(self, fsync: bool = True) -> None:
        """Flush now (and fsync unless ``fsync=False``)."""
        if self._f is not None:
            self._f.flush()
            if fsync:
                os.fsync(self._f.fileno())
                self._last_sync = time.monotonic()

    def close(self) -> None:
        """Flush, fsync and close (idempotent)."""
        if self._f is None:
            return
        try:
            self.flush(fsync=True)
        finally:
            self._f.close()
            self._f = None

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has been called."""
        return self._f is None

    def __enter__(self) -> RecordWriter:
        """Use as a context manager; closes (with fsync) on exit."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the writer."""
        self.close()


def write_record(path: PathArg, record: Record) -> None:
    """Write ``record`` as a whole file, atomically (temporary file, then ``os.replace``).

    Columns are :data:`DEFAULT_COLUMNS` in that order (without ``temp_c`` when
    ``record.temp_c`` is None); metadata in ``record.meta`` order with ``format`` first.
    """
    path = str(path)
    tmp = f"{path}.tmp-{os.getpid()}"
    try:
        with RecordWriter(
            tmp, record.meta, columns=record.columns(), fsync_interval_s=math.inf, overwrite=True
        ) as w:
            w.write_rows(
                record.t_s,
                record.m1_pix,
                record.m2_pix,
                record.tilt_x_arcsec,
                record.tilt_y_arcsec,
                record.step,
                record.temp_c,
            )
        os.replace(tmp, path)
        _fsync_dir(path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


# --------------------------------------------------------------------------- benchmark


def _synthetic(n: int = 33_000, seed: int = 0) -> Record:
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


def _bench(argv: list[str] | None = None) -> None:
    """Print read speed (rows/s) for PATH, or for a synthetic 33 000-row record."""
    import tempfile

    args = sys.argv[1:] if argv is None else argv
    with tempfile.TemporaryDirectory() as d:
        if args:
            path = args[0]
        else:
            path = os.path.join(d, "synthetic.csv")
            t0 = time.perf_counter()
            write_record(path, _synthetic())
            print(f"wrote 33000 rows in {time.perf_counter() - t0:.3f} s")
        best = math.inf
        n = 0
        for _ in range(5):
            t0 = time.perf_counter()
            rec = read_record(path)
            best = min(best, time.perf_counter() - t0)
            n = rec.n
        print(f"{path}: {n} rows in {best * 1e3:.1f} ms (best of 5): {n / best:,.0f} rows/s")


if __name__ == "__main__":
    _bench()
