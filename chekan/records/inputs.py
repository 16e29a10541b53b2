"""Any calibration input, a record or a legacy protocol: opened by its ``# format:`` line
(:func:`read_input`) and made ready for calibration (:func:`ready_input`: a record's angles
corrected by the platform's angle calibration, its holds found with what of the tilt
program they lack; a protocol as it is)."""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from chekan.errors import ChekanError, FormatError
from chekan.records import FORMAT as RECORD_FORMAT
from chekan.records import Record, read_record
from chekan.records.anglecal import AngleCalibration, calibrated
from chekan.records.holds import HoldTable, program_coverage, segment_record, settle_of
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


@dataclass(frozen=True)
class ReadyInput:
    """One input as every method takes it: ``data`` (a record with its angle calibration
    applied, or a protocol), its ``kind`` ("record" or "protocol"), and of a record its
    ``holds`` (:func:`~chekan.records.holds.segment_record`) and what of the tilt program
    they lack (:func:`~chekan.records.holds.program_coverage`; None where nothing is)."""

    data: Record | Protocol
    kind: str
    holds: HoldTable | None = None
    coverage: dict | None = None


def ready_input(
    data: Record | Protocol,
    *,
    angle_calibration: str | Path | AngleCalibration | None = None,
    settle_s: float | None = None,
    input_path: str | Path | None = None,
) -> ReadyInput:
    """``data`` ready for calibration. ``angle_calibration``: a table (or its file) that
    overrides the one the record's header names; ``settle_s`` None: the record's
    ``program_settle_s``, else 300 s; ``input_path``: the file ``data`` was read from (a
    header's table is found beside it; messages name it)."""
    if isinstance(data, Protocol):
        if angle_calibration is not None:
            raise ChekanError(
                f"{input_path or 'protocol'}: an angle calibration corrects a record's measured"
                " angles; a legacy protocol holds only its commanded angles"
            )
        return ReadyInput(data, "protocol")
    if not isinstance(data, Record):
        raise ChekanError(f"cannot calibrate a {type(data).__name__}: give a Record or a Protocol")
    record = calibrated(data, angle_calibration, input_path)
    holds = segment_record(record, settle_s=settle_of(record, settle_s))
    return ReadyInput(record, "record", holds, program_coverage(holds, record.meta))
