"""Open any calibration input by its ``# format:`` line: a record or a legacy protocol."""

from __future__ import annotations

from os import PathLike

from chekan.errors import FormatError
from chekan.records import FORMAT as RECORD_FORMAT
from chekan.records import Record, read_record
from chekan.records.protocol import FORMAT as PROTOCOL_FORMAT
from chekan.records.protocol import Protocol, read_protocol

KINDS = {RECORD_FORMAT: "record", PROTOCOL_FORMAT: "protocol"}


def _sniff(path: str | PathLike) -> tuple[str, int | None]:
    """The ``format`` value and its line, reading only the metadata block."""
    with open(path, "rb") as f:
        for lineno, raw in enumerate(f, start=1):
            if lineno == 1 and raw.startswith(b"\xef\xbb\xbf"):
                raw = raw[3:]
            if not raw.startswith(b"#"):
                break
            line = raw.rstrip(b"\r\n")
            if line.startswith(b"# format: "):
                return line[len(b"# format: ") :].decode("utf-8", "replace").strip(), lineno
    raise FormatError(
        path, None, "no '# format:' metadata line (not a chekan-record/1 or chekan-protocol/1 file)"
    )


def input_kind(path: str | PathLike) -> str:
    """``"record"`` or ``"protocol"`` from the file's ``# format:`` line."""
    fmt, line = _sniff(path)
    if fmt not in KINDS:
        raise FormatError(
            path, line, f"unknown format {fmt!r} (expected {RECORD_FORMAT} or {PROTOCOL_FORMAT})"
        )
    return KINDS[fmt]


def read_input(path: str | PathLike) -> Record | Protocol:
    """Read a record or a protocol, whichever the file's ``# format:`` line says."""
    if input_kind(path) == "record":
        return read_record(path)
    return read_protocol(path)
