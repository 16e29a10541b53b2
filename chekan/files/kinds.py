"""What kind of file an existing path holds, and which file names each kind goes under.

:func:`sniff_kind` recognises every file that chekan reads or writes in a format of its
own (records, protocols, angle-calibration tables, results, truths, design and history
JSON, programs, lab files, DCC, PDF and HTML certificates, posterior NetCDF, archive
exports, the SQLite archive) from its first 64 kB; :data:`SUFFIXES` are the file name
suffixes of each kind. :mod:`chekan.files.outputs` uses both to refuse an output that would
destroy a file of another kind or put one format under another's name. Stdlib only.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

PathArg = str | os.PathLike[str]

RECORD = "chekan-record/1"
PROTOCOL = "chekan-protocol/1"
ANGLE_CALIBRATION = "chekan-angle-calibration/1"
RESULT = "chekan-result/1"
TRUTH = "chekan-truth/1"
DESIGN = "chekan-design/1"
HISTORY = "chekan-history/1"
SQLITE = "SQLite database"
PROGRAM = "tilt program (TOML)"
LAB = "lab file (TOML)"
DCC = "DCC (XML)"
PDF = "PDF"
HTML = "HTML page"
NETCDF = "NetCDF file"
EXPORT = "archive export (CSV)"
PNG = "PNG image"
SVG = "SVG image"
#: an output folder (its files are the command's business): see :class:`chekan.files.outputs.Output`
FOLDER = "folder"

#: The kind of file each ``--format`` of a certificate writes.
REPORT_KINDS = {"pdf": PDF, "html": HTML, "dcc": DCC}
_REPORT_SUFFIXES = {".pdf": PDF, ".html": HTML, ".htm": HTML, ".xml": DCC}


def report_kind(out: PathArg, fmt: str | None = None) -> str | None:
    """The kind of certificate written to ``out`` in format ``fmt`` (default: from the
    suffix); ``None`` when neither tells (:func:`chekan.report.output_format` refuses it)."""
    if fmt is not None:
        return REPORT_KINDS.get(fmt)
    return _REPORT_SUFFIXES.get(Path(out).suffix.lower())


#: Irreplaceable measurement files that no output option may overwrite.
PROTECTED_FORMATS = (RECORD, PROTOCOL, ANGLE_CALIBRATION)

#: The file name suffixes of each kind that an output writes (the first is the usual one).
SUFFIXES: dict[str, tuple[str, ...]] = {
    RECORD: (".csv",),
    PROTOCOL: (".csv",),
    ANGLE_CALIBRATION: (".csv",),
    RESULT: (".json",),
    TRUTH: (".json",),
    DESIGN: (".json",),
    HISTORY: (".json",),
    SQLITE: (".sqlite", ".sqlite3", ".db"),
    PROGRAM: (".toml",),
    LAB: (".toml",),
    DCC: (".xml",),
    PDF: (".pdf",),
    HTML: (".html", ".htm"),
    NETCDF: (".nc", ".nc4", ".netcdf", ".h5", ".hdf5"),
    EXPORT: (".csv",),
    PNG: (".png",),
    SVG: (".svg",),
}
#: Every suffix that says which format a file holds (others, or none, say nothing).
KNOWN_SUFFIXES = frozenset(s for v in SUFFIXES.values() for s in v)

_JSON_FORMATS = frozenset({RESULT, DESIGN, HISTORY, TRUTH})
_JSON_FORMAT = re.compile(r'"format"\s*:\s*"(chekan-[a-z-]+/\d+)"')
_SQLITE_MAGIC = b"SQLite format 3\x00"
_SQLITE_SIDECARS = ("-wal", "-shm", "-journal")
_NETCDF_MAGIC = (b"\x89HDF\r\n\x1a\n", b"CDF\x01", b"CDF\x02", b"CDF\x05")
_PROGRAM_KEYS = frozenset({"angles", "dwell_s", "rounds", "settle_s", "axis", "order", "sequence"})
_LAB_KEYS = frozenset({"lab", "responsible"})
_EXPORT_HEADER = b"session_id,serial,calibrated_on,method,"
_SNIFF_BYTES = 1 << 16


_AN = frozenset({SQLITE, HTML, EXPORT, SVG})


def noun(kind: str | None) -> str:
    """``kind`` with its article, for a message: "a chekan-result/1 file", "an HTML page"."""
    if kind is None:
        return "a file of another kind"
    if kind.startswith("chekan-"):
        return f"a {kind} file"
    return f"{'an' if kind in _AN else 'a'} {kind}"


def sniff_format(path: PathArg) -> str | None:
    """The ``# format:`` value of the leading ``# key: value`` block, or ``None``.

    Reads at most 64 kB; a file that cannot be read or is not such a file gives ``None``.
    """
    head = _head(path)
    if head is None:
        return None
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
    for raw in head.split(b"\n"):
        if not raw.startswith(b"#"):
            return None
        line = raw.rstrip(b"\r")
        if line.startswith(b"# format:"):
            return line[len(b"# format:") :].decode("utf-8", "replace").strip()
    return None


def sniff_kind(path: PathArg) -> str | None:
    """What an existing file is, as far as the outputs guard cares (``None``: nothing known).

    One of this module's kinds: a ``# format:`` CSV (:func:`sniff_format`), an SQLite
    database (by its 16-byte header; also its ``-wal``/``-shm``/``-journal`` files), a
    chekan JSON by its ``"format"``, a tilt program or a lab file (TOML with their keys),
    a DCC (XML whose root is ``digitalCalibrationCertificate``), a PDF, an HTML page, a
    NetCDF file, an archive export or a PNG/SVG image. Reads at most 64 kB.
    """
    p = Path(path)
    head = _head(p)
    if head is None:
        return None
    binary = _binary_kind(p, head)
    if binary is not None:
        return binary
    fmt = sniff_format(p)
    if fmt is not None:
        return fmt
    if head.startswith(_EXPORT_HEADER):
        return EXPORT
    text = head.decode("utf-8", "replace").lstrip("\ufeff").lstrip()
    if text.startswith("{"):  # the first chekan "format" (the writers put theirs first)
        for m in _JSON_FORMAT.finditer(text):
            if m.group(1) in _JSON_FORMATS:
                return m.group(1)
        return None
    if text.startswith("<"):
        return _markup_kind(text)
    keys = _toml_keys(text)
    if _PROGRAM_KEYS & keys:
        return PROGRAM
    if _LAB_KEYS & keys:
        return LAB
    return None


def _head(path: PathArg) -> bytes | None:
    try:
        with open(path, "rb") as f:
            return f.read(_SNIFF_BYTES)
    except OSError:
        return None


def _binary_kind(p: Path, head: bytes) -> str | None:
    """An SQLite database (or its journal), a PDF, a NetCDF file or a PNG image."""
    if head.startswith(_SQLITE_MAGIC):
        return SQLITE
    for suffix in _SQLITE_SIDECARS:
        if p.name.endswith(suffix) and sniff_kind(p.with_name(p.name[: -len(suffix)])) == SQLITE:
            return SQLITE
    if head.startswith(b"%PDF-"):
        return PDF
    if head.startswith(_NETCDF_MAGIC):
        return NETCDF
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return PNG
    return None


def _markup_kind(text: str) -> str | None:
    """A DCC, an HTML page or an SVG image from the start of a markup file."""
    start = text[:4096].lower()
    if "digitalcalibrationcertificate" in start:
        return DCC
    if start.startswith(("<!doctype html", "<html")):
        return HTML
    if "<svg" in start:
        return SVG
    return None


def _toml_keys(text: str) -> set[str]:
    """Top-level keys of ``text`` read as TOML (empty when it is not TOML)."""
    import tomllib

    try:
        return set(tomllib.loads(text))
    except (tomllib.TOMLDecodeError, ValueError):
        return set()
