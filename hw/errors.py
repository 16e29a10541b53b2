"""Typed errors of the hardware layer (one class per way a link or a device fails)."""

from __future__ import annotations

from chekan.errors import ChekanError


class HwError(ChekanError):
    """Base class of the hardware layer's errors."""


class LinkLost(HwError):
    """The port failed (unplugged, pty closed, open refused): close it and reopen."""

    def __init__(self, port: str, reason: str):
        self.port = port
        self.reason = reason
        super().__init__(f"{port}: link lost ({reason})")


class ReplyTimeout(HwError):
    """A query got no matching reply in time (the line may have been lost: retry)."""

    def __init__(self, port: str, query: str, timeout_s: float):
        self.port = port
        self.query = query
        self.timeout_s = timeout_s
        super().__init__(f"{port}: no reply to {query} within {timeout_s:g} s")


class DeviceError(HwError):
    """The device refused a command (e.g. ``$PLA,TILT,ERR,RANGE``) or misbehaved."""

    def __init__(self, port: str, command: str, reason: str):
        self.port = port
        self.command = command
        self.reason = reason
        super().__init__(f"{port}: {command} refused: {reason}")


class GaveUp(HwError):
    """A link stayed down (or silent) beyond the give-up limit."""

    def __init__(self, port: str, down_s: float, attempts: int, last_error: str = ""):
        self.port = port
        self.down_s = down_s
        self.attempts = attempts
        extra = f"; last error: {last_error}" if last_error else ""
        super().__init__(
            f"{port}: gave up after {down_s:.1f} s without data ({attempts} reopen attempts{extra})"
        )


class DwellCut(HwError):
    """A step's dwell was cut short (samples lost, hold lost, platform silent) so often
    that no uninterrupted dwell of its full length came: the link or the platform is
    unreliable. The run levels and stops; ``--resume`` runs the step again."""

    def __init__(self, step: int, label: str, dwell_s: float, cuts: int):
        self.step = step
        self.cuts = cuts
        super().__init__(
            f"step {step} ({label}): gave up after its dwell was cut short {cuts} times "
            f"(samples lost, hold lost or the platform silent): no uninterrupted dwell of "
            f"{dwell_s:g} s on the sample clock; check the links, then resume (--resume)"
        )


class StorageFailed(HwError):
    """A file of the run (record, journal, raw log) cannot be written: a full disk, an I/O
    error. Fatal: the run levels the platform and stops; the record ends at its last
    complete row and can be resumed once the disk has room."""

    def __init__(self, path: str, error: OSError, t_s_last: float | None):
        self.path = path
        self.error = error
        self.t_s_last = t_s_last
        why = error.strerror or str(error)
        end = (
            ""
            if t_s_last is None
            else f"; the record is closed with its last row at t_s {t_s_last:g} and can be "
            "resumed (--resume) once the disk has room"
        )
        super().__init__(f"cannot write {path}: {why}{end}")


class RunRefused(ChekanError):
    """A run cannot start as asked: the request is at fault, not a device."""


class RecordExists(RunRefused):
    """The record (or its journal) of a new run already exists."""

    def __init__(self, path: str):
        self.path = path
        super().__init__(f"{path} exists: resume that run or write the record elsewhere")


class BadMetadata(RunRefused):
    """User metadata for the record's header that the header cannot take."""

    def __init__(self, problem: str):
        self.problem = problem
        super().__init__(f"record metadata: {problem}")


class PortsUnknown(RunRefused):
    """A resumed run whose journal does not say where the devices are."""

    def __init__(self) -> None:
        super().__init__(
            "resume: the ports are not in the journal: give the sensor and platform URLs"
        )
