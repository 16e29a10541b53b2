"""The files of a run: the record (rows), its journal (events) and the raw log (lines).

- ``rec.csv`` — :class:`chekan.records.RecordWriter` (flush per batch of rows, fsync
  every ``fsync_interval_s``);
- ``rec.csv.journal.jsonl`` — :mod:`hw.journal`, fsynced per event; the rows of the
  current batch are written first, so the record is never behind its journal;
- ``rec.csv.raw.log`` — every received (and sent) line with its port.

A write that fails (a full disk, an I/O error) stops the recording: each file ends at its
last whole line, later rows are not taken, later events are tried (they may fit) but never
raise, and :attr:`Recorder.failure` tells the runner to level and stop.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from chekan.records import RecordWriter
from hw.drivers import PlatformInfo, SensorInfo
from hw.errors import StorageFailed
from hw.events import Event
from hw.journal import Journal, journal_path, raw_log_path
from hw.linkio import RawLog
from hw.nmea import Grv

Row = tuple[float, float, float, float, float, float, float]


class EventLog(Protocol):
    """Something that journals an event (``event`` name and its fields)."""

    def __call__(self, event: str, /, **fields: object) -> None: ...


@dataclass
class RecordStats:
    """Rows written in this session and the sensor flags seen in them."""

    samples: int = 0
    t_s_first: float | None = None
    t_s_last: float | None = None
    saturated: int = 0
    therm: int = 0


def record_meta(
    sensor: SensorInfo,
    platform: PlatformInfo,
    *,
    rate_hz: float,
    program: str,
    dwell_s: float | None,
    settle_s: float | None,
    started: str,
    user: dict[str, str],
    steps: int | None = None,
) -> dict[str, str]:
    """Header of a new record: what the devices reported, the program (its number of steps:
    what a calibration checks the record against), then the user's keys."""
    meta = {
        "format": "chekan-record/1",
        "serial": sensor.serial,
        "instrument": "Chekan-AM",
        "model": sensor.model,
        "platform_serial": platform.serial,
        "started": started,
        "sample_rate_hz": f"{rate_hz:g}",
        "program": program,
    }
    if dwell_s is not None and settle_s is not None:
        meta["program_dwell_s"] = f"{dwell_s:g}"
        meta["program_settle_s"] = f"{settle_s:g}"
    if steps:
        meta["program_steps"] = str(steps)
    meta["sensor_firmware"] = sensor.firmware
    meta["platform_firmware"] = platform.firmware
    meta.update(user)
    return meta


class Recorder:
    """Owns the record writer, the journal and the raw log of one session."""

    def __init__(self, path: Path, *, fsync_interval_s: float, clock: Callable[[], float]):
        self.path = path
        self._fsync_interval_s = fsync_interval_s
        self._clock = clock
        self.journal: Journal | None = None
        self.raw: RawLog | None = None
        self.writer: RecordWriter | None = None
        self.stats = RecordStats()
        self._rows: list[Row] = []  # rows of the current pump cycle
        self._sensor_status = "OK"
        self.failure: StorageFailed | None = None  # the first write that failed

    @property
    def recording(self) -> bool:
        """Whether the record is open (rows are accepted)."""
        return self.writer is not None and not self.writer.closed

    def _failed(self, path: str | Path, e: OSError) -> None:
        """Remember the first failed write; the record is closed at its last complete row."""
        if self.failure is None:
            t_last = self.writer.last_t if self.writer is not None else None
            self.failure = StorageFailed(str(path), e, t_last)
        if self.writer is not None and not self.writer.closed:
            try:
                self.writer.close()
            except OSError:
                pass

    def check(self) -> StorageFailed | None:
        """The failure of any file of the run so far (the raw log's threads included)."""
        if self.failure is None and self.raw is not None and self.raw.error is not None:
            self._failed(self.raw.path, self.raw.error)
        return self.failure

    def open_journal(self) -> None:
        """Open (and lock) the journal; a second runner on the record fails here."""
        self.journal = Journal(journal_path(self.path))

    def open_raw_log(self) -> RawLog:
        """Open the raw log (the links write into it)."""
        self.raw = RawLog(raw_log_path(self.path), clock=self._clock)
        return self.raw

    def event(self, event: str, /, **fields: object) -> None:
        """Journal ``event`` (after writing the pending rows); a failed write is remembered."""
        self.flush()
        if self.journal is not None:
            try:
                self.journal.write(event, **fields)
            except OSError as e:
                self._failed(self.journal.path, e)

    def create(self, meta: dict[str, str]) -> None:
        """Start a new record with the header ``meta`` (refuses an existing file)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self.writer = RecordWriter(self.path, meta, fsync_interval_s=self._fsync_interval_s)
        except FileExistsError:
            raise
        except OSError as e:  # no room even for the header
            self._failed(self.path, e)
            assert self.failure is not None
            raise self.failure from None

    def remove_if_unborn(self) -> bool:
        """After the run: if the record was never written (missing or empty), remove it and
        its journal, which hold nothing to resume and would block a retry; the raw log stays
        if the devices said anything (a retry appends to it), else it goes too."""
        raw = raw_log_path(self.path)
        try:
            if self.path.exists() and self.path.stat().st_size > 0:
                return False
            for p in (self.path, journal_path(self.path)):
                p.unlink(missing_ok=True)
            if raw.exists() and raw.stat().st_size == 0:
                raw.unlink()
        except OSError:
            return False
        return True

    def append(self) -> str | None:
        """Reopen the record to continue it; returns where a torn last line was saved."""
        self.writer = RecordWriter(
            self.path, None, append=True, fsync_interval_s=self._fsync_interval_s
        )
        return self.writer.torn_path

    def add_sample(
        self, t: float, g: Grv, angles: tuple[float, float] | None, step: int | None
    ) -> None:
        """Queue the row of one sample; count it; journal SAT / THERM episodes."""
        if not self.recording:
            return
        nan = math.nan
        self._rows.append(
            (
                t,
                nan if g.m1 is None else g.m1,
                nan if g.m2 is None else g.m2,
                angles[0] if angles else nan,
                angles[1] if angles else nan,
                nan if step is None else step,
                nan if g.temp is None else g.temp,
            )
        )
        s = self.stats
        s.samples += 1
        if s.t_s_first is None:
            s.t_s_first = t
        s.t_s_last = t
        if g.status == "SAT":
            s.saturated += 1
        elif g.status == "THERM":
            s.therm += 1
        if g.status != self._sensor_status:
            self.event(Event.SENSOR_STATUS, status=g.status, was=self._sensor_status or None, t_s=t)
            self._sensor_status = g.status

    def flush(self) -> None:
        """Write the rows of this pump cycle (one write per batch); after a failed write the
        batch is not counted (the record ends at its last complete row)."""
        if not self._rows:
            return
        rows, self._rows = self._rows, []
        if not self.recording:
            self._uncount(rows)
            return
        assert self.writer is not None
        try:
            self.writer.write_rows(*(list(c) for c in zip(*rows, strict=True)))
        except OSError as e:
            self._uncount(rows)
            self._failed(self.path, e)

    def _uncount(self, rows: list[Row]) -> None:
        s = self.stats
        s.samples -= len(rows)
        s.t_s_last = self.writer.last_t if self.writer is not None else None
        if s.samples == 0:
            s.t_s_first = s.t_s_last = None

    def close_record(self) -> None:
        """Write what is pending and close the record."""
        if self.writer is not None:
            try:
                self.flush()
            finally:
                try:
                    self.writer.close()
                except OSError as e:
                    self._failed(self.path, e)

    def close_raw_log(self) -> None:
        """Write the raw log's last lines and close it (the ports are closed)."""
        if self.raw is not None:
            self.raw.close()

    def close(self) -> None:
        """Close the journal and the raw log (after the last event)."""
        if self.journal is not None:
            self.journal.close()
        if self.raw is not None:
            self.raw.close()
