"""Framing shared by ``chekan-record/1`` and ``chekan-protocol/1`` files.

Both formats (``docs/specs/record-format.md``, ``legacy-protocol.md``) are a UTF-8
file of ``# key: value`` metadata lines, one comma-separated column header line and
CSV data rows. This module splits such a file into its parts (:func:`read_frame`),
normalises the data block (:func:`data_block`) and holds the helpers both readers
share: the incomplete-final-line warning, the field-count message and metadata numbers.
Every problem is a :class:`~chekan.errors.FormatError` naming the file and the line.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass
from os import PathLike

from chekan.errors import FormatError

BOM = b"\xef\xbb\xbf"
_META_RE = re.compile(r"# ([a-z0-9_]+): (.*)", re.DOTALL)

PathArg = str | PathLike


class IncompleteLineWarning(UserWarning):
    """An incomplete final line (interrupted write) was skipped."""


# --------------------------------------------------------------------------- framing


@dataclass
class Frame:
    """Metadata, header and the raw data block of a framed CSV file."""

    meta: dict[str, str]
    meta_lines: dict[str, int]
    columns: list[str]
    header_line: int  # 1-based physical line of the header
    data: bytes  # everything after the header line's newline


def decode_line(line: bytes, path: PathArg, lineno: int) -> str:
    """Decode one line as UTF-8; a FormatError names the line and the bad byte."""
    try:
        return line.decode("utf-8")
    except UnicodeDecodeError as e:
        raise FormatError(
            path, lineno, f"not UTF-8 text (byte 0x{line[e.start]:02x} at column {e.start + 1})"
        ) from None


def read_frame(raw: bytes, path: PathArg, expected_format: str | None) -> Frame:
    """Split ``raw`` into metadata, header and data; check the framing and ``format``.

    ``expected_format=None`` accepts any format value (used for sniffing).
    """
    if raw.startswith(BOM):
        raw = raw[len(BOM) :]
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
        text = decode_line(line, path, lineno)
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
    header = decode_line(line, path, lineno)
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
    return Frame(meta, meta_lines, columns, lineno, raw[pos:])


def data_block(data: bytes) -> tuple[bytes, bool]:
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


def last_line_start(block: bytes) -> int:
    """Offset of the last line of a non-empty ``\\n``-terminated block."""
    return block.rfind(b"\n", 0, len(block) - 1) + 1


def warn_incomplete(
    path: PathArg, lineno: int, why: str, sink: list[str], stacklevel: int = 4
) -> None:
    """Record and emit the warning for a skipped incomplete final line."""
    msg = f"{path}:{lineno}: incomplete last line skipped ({why})"
    sink.append(msg)
    warnings.warn(msg, IncompleteLineWarning, stacklevel=stacklevel)


def read_bytes(path: PathArg, max_rows: int | None) -> bytes:
    """The file's bytes; with ``max_rows`` only metadata, header and that many rows."""
    if max_rows is None:
        with open(path, "rb") as f:
            return f.read()
    parts: list[bytes] = []
    rows = -1  # the header line is not a row
    with open(path, "rb") as f:
        for line in f:
            parts.append(line)
            if line.startswith((b"#", BOM + b"#")) and rows < 0:
                continue
            rows += 1
            if rows >= max_rows:
                break
    return b"".join(parts)


def count_problem(line: bytes, k: int, ncols: int) -> str:
    """Message for a row with ``k`` fields where the header has ``ncols``."""
    what = f"row has {k} field{'s' if k != 1 else ''}, header has {ncols}"
    return f"empty line ({what})" if not line.strip() else what


#: Gravity on the Earth's surface, mGal: ≈ 976 000 (equator, high mountains) to 984 000 (poles,
#: deep mines); a value outside it is a mistaken unit (9.81 m/s²) or a typing error.
G_EARTH_MGAL = (976_000.0, 984_000.0)


def check_gravity_mgal(value: float, path: PathArg | None, line: int | None, what: str) -> float:
    """``value`` (mGal) if it lies in :data:`G_EARTH_MGAL`, else a :class:`FormatError`."""
    lo, hi = G_EARTH_MGAL
    if not lo <= value <= hi:
        raise FormatError(
            path,
            line,
            f"{what} {value:g} mGal is outside the Earth's gravity ({lo:.0f}–{hi:.0f} mGal); "
            "the unit is mGal (9.81 m/s² is 981 000 mGal)",
        )
    return value


def meta_float(
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


def count_rows(path: PathArg, chunk_bytes: int = 1 << 20) -> int:
    """Data rows of a framed file (lines after the column header; a last line without its
    newline counts), read in chunks: the memory used does not grow with the file."""
    rows = 0
    last = b"\n"
    with open(path, "rb") as f:
        for raw in f:  # metadata lines, then the header line
            if not raw.removeprefix(BOM).startswith(b"#"):
                break
        while chunk := f.read(chunk_bytes):
            rows += chunk.count(b"\n")
            last = chunk[-1:]
    if last != b"\n":
        rows += 1
    return rows
