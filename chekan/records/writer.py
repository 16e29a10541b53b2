"""Writers of ``chekan-record/1`` files: whole-file and atomic, or streaming and crash-safe.

:func:`write_record` writes a :class:`~chekan.records.reader.Record` to a temporary
file and renames it into place. :class:`RecordWriter` streams rows: every line is
flushed as it is written, fsync'ed at most every ``fsync_interval_s``, and
``append=True`` resumes a record after a crash without losing anything (a torn last
line is saved aside).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import time
from collections.abc import Iterable, Sequence
from typing import IO, Any

import numpy as np

from chekan.errors import FormatError
from chekan.files.durable import append_whole, fsync_dir
from chekan.records.framing import PathArg, read_frame
from chekan.records.reader import DEFAULT_COLUMNS, FORMAT, REQUIRED_COLUMNS, Record

_KEY_RE = re.compile(r"[a-z0-9_]+")
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


class RecordWriter:
    """Streaming, append-only, crash-safe writer of a ``chekan-record/1`` file.

    A new file gets the metadata (``format`` first) and the header at once. With
    ``append=True`` an existing record is continued after its last complete line;
    a torn final line is cut off and its bytes saved to ``<path>.torn-<n>``. ``meta``
    may then be ``None``; if given, each of its keys must be in the file with the
    same value (metadata cannot be added once data follow). The column order of an
    appended file is the file's own; its set of columns must equal ``columns``.

    Every batch of lines goes to the file as one unbuffered write; ``os.fsync`` runs at
    most every ``fsync_interval_s`` (monotonic clock) and on :meth:`close`. Rows whose
    time would go backwards are refused (``ValueError``), so the file stays valid. A write
    that fails (``OSError``: a full disk, an I/O error) is cut back to the last complete
    row, the file is closed and the error raised: the record stays a valid record that
    ``append=True`` continues. An existing file is never overwritten unless
    ``overwrite=True``.
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
        self.error: OSError | None = None  # the write that closed the writer
        self._f: IO[bytes] | io.RawIOBase | None = None
        self._good = 0  # end of the last complete write
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
            fh = open(self.path, mode, buffering=0)
            try:
                self._good = append_whole(fh, text.encode("utf-8"), 0)
                os.fsync(fh.fileno())
            except OSError:
                fh.close()
                raise
            self._f = fh
            fsync_dir(self.path)
        self._last_sync = time.monotonic()

    def _open_append(self, meta: dict[str, str] | None, cols: tuple[str, ...]) -> tuple[str, ...]:
        """Check an existing record, cut a torn last line aside, open it for appending."""
        with open(self.path, "rb") as f:
            raw = f.read()
        fr = read_frame(raw, self.path, FORMAT)
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
            n = 1
            while os.path.exists(f"{self.path}.torn-{n}"):
                n += 1
            self.torn_path = f"{self.path}.torn-{n}"
            with open(self.torn_path, "xb") as t:
                t.write(torn)
                t.flush()
                os.fsync(t.fileno())
            fsync_dir(self.path)
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
        fa = open(self.path, "r+b", buffering=0)
        try:
            fa.truncate(cut)
            fa.seek(cut)
            self._good = cut
            if cut == len(raw) and not raw.endswith(b"\n"):  # complete header, no newline yet
                self._good = append_whole(fa, b"\n", cut)
            os.fsync(fa.fileno())
        except OSError:
            fa.close()
            raise
        self._f = fa
        return tuple(fr.columns)

    # -- writing

    def _emit(self, data: bytes) -> None:
        f = self._f
        if f is None:
            raise ValueError(f"{self.path}: writer is closed")
        try:
            self._good = append_whole(f, data, self._good)
            now = time.monotonic()
            if now - self._last_sync >= self.fsync_interval_s:
                os.fsync(f.fileno())
                self._last_sync = now
        except OSError as e:
            self._fail(e)
            raise

    def _fail(self, e: OSError) -> None:
        """Close after a failed write; the file ends at the last complete row."""
        self.error = e
        f, self._f = self._f, None
        if f is not None:
            with contextlib.suppress(OSError):
                os.fsync(f.fileno())
            f.close()

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
        if self._f is not None and fsync:
            try:
                os.fsync(self._f.fileno())
            except OSError as e:
                self._fail(e)
                raise
            self._last_sync = time.monotonic()

    def close(self) -> None:
        """Flush, fsync and close (idempotent)."""
        if self._f is None:
            return
        try:
            self.flush(fsync=True)
        finally:
            if self._f is not None:
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
        fsync_dir(path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
