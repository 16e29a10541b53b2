"""Incremental readers of files another process is writing (record, journal, raw log).

Each follower remembers the byte offset it has read up to and keeps an unfinished
last line aside until its newline arrives, so a torn line (the writer is mid-write,
or was killed mid-write) is never parsed. They only ever open the files for reading:
nothing they do can slow or endanger the writer. A file that shrinks (replaced or
truncated) is read again from the start.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np

from chekan.errors import FormatError
from chekan.records.framing import read_frame
from chekan.records.reader import FORMAT, REQUIRED_COLUMNS
from hw.nmea import SentenceParser

#: the columns the live page keeps, in this order (``temp_c`` may be absent: NaN)
COLUMNS = ("t_s", "m1_pix", "m2_pix", "tilt_x_arcsec", "tilt_y_arcsec", "step", "temp_c")

_CHUNK = 8 << 20  # at most this many bytes per poll
_MAX_HEADER = 64 << 10  # a header longer than this (or a line without an end) is no record


class _Tail:
    """New complete lines of a growing file since the last call."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.offset = 0
        self._partial = b""
        self.resets = 0

    def reset(self) -> None:
        self.offset, self._partial = 0, b""
        self.resets += 1

    def lines(self) -> list[bytes]:
        try:
            size = os.stat(self.path).st_size
        except FileNotFoundError:
            return []
        if size < self.offset:  # truncated or replaced: start again
            self.reset()
            return [b"\x00reset"]
        if size == self.offset:
            return []
        with open(self.path, "rb") as f:
            f.seek(self.offset)
            data = f.read(min(size - self.offset, _CHUNK))
        self.offset += len(data)
        data = self._partial + data
        *complete, self._partial = data.split(b"\n")
        return complete

    @property
    def pending(self) -> bytes:
        """The unfinished last line (a torn line stays here until completed)."""
        return self._partial


def _num(s: bytes) -> float:
    s = s.strip()
    return float(s) if s else math.nan


class RecordFollower:
    """Follows a ``chekan-record/1`` file: header first, then new rows on every :meth:`poll`.

    Malformed rows are counted in :attr:`bad_rows` and skipped (the page must not stop
    on them; the analysis proper reports them with file and line). A file that is no
    record (no ``# format: chekan-record/1`` header: a binary file, another CSV) or whose
    ``t_s`` runs backwards sets :attr:`problem`, the reader's own message naming the file
    and line (``rec.csv:519: t_s goes backwards (400.0 after 499.0)``); rows of a record
    whose time runs backwards are still returned (for the plot).
    """

    def __init__(self, path: str | Path):
        self._tail = _Tail(path)
        self.path = self._tail.path
        self._clear()

    def _clear(self) -> None:
        self.meta: dict[str, str] = {}
        self.columns: tuple[str, ...] | None = None
        self._index: list[int | None] = []
        self.bad_rows = 0
        self.rows = 0
        self.problem: str | None = None
        self._header = bytearray()
        self._line_no = 0  # physical lines read so far
        self._last_t: float | None = None

    def _check_header(self) -> None:
        """The reader's checks of the header (format line, columns), its message on failure."""
        try:
            fr = read_frame(bytes(self._header), self.path, FORMAT)
            missing = [c for c in REQUIRED_COLUMNS if c not in fr.columns]
            if missing:
                raise FormatError(
                    self.path, fr.header_line, f"missing required column {missing[0]!r}"
                )
        except FormatError as e:
            self.problem = str(e)

    @property
    def offset(self) -> int:
        return self._tail.offset

    @property
    def pending(self) -> bytes:
        return self._tail.pending

    def poll(self) -> dict[str, np.ndarray] | None:
        """Rows completed since the last call as arrays keyed by :data:`COLUMNS`, or None.

        Returns ``{"reset": True}`` (after which the caller starts afresh) if the file
        was replaced.
        """
        out: list[list[float]] = []
        for raw in self._tail.lines():
            if raw == b"\x00reset":
                self._clear()
                return {"reset": np.array(True)}
            self._line_no += 1
            if self.problem is not None and self.columns is None:
                continue  # not a record: nothing to read
            line = raw.rstrip(b"\r")
            if self.columns is None:
                self._header += raw + b"\n"
                if line.startswith(b"#"):
                    text = line.decode("utf-8", "replace")
                    m = re.match(r"#\s*([a-z0-9_]+):\s?(.*)$", text)
                    if m:
                        self.meta[m[1]] = m[2]
                    continue
                if not line.strip():
                    continue
                self._check_header()
                if self.problem is not None:
                    continue
                self.columns = tuple(c.strip() for c in line.decode("ascii", "replace").split(","))
                pos = {c: i for i, c in enumerate(self.columns)}
                self._index = [pos.get(c) for c in COLUMNS]
                continue
            if not line.strip():
                continue
            fields = line.split(b",")
            if len(fields) != len(self.columns):
                self.bad_rows += 1
                continue
            try:
                row = [math.nan if i is None else _num(fields[i]) for i in self._index]
            except ValueError:
                self.bad_rows += 1
                continue
            t = row[0]
            if self._last_t is not None and t < self._last_t and self.problem is None:
                where = f"{self.path}:{self._line_no}"
                self.problem = f"{where}: t_s goes backwards ({t!r} after {self._last_t!r})"
            self._last_t = t if t == t else self._last_t
            out.append(row)
        if self.columns is None and self.problem is None and len(self._tail.pending) > _MAX_HEADER:
            self.problem = f"{self.path}: no line end in {_MAX_HEADER} bytes (not a record)"
        if not out:
            return None
        arr = np.asarray(out, dtype=float)
        self.rows += len(out)
        return {c: arr[:, k] for k, c in enumerate(COLUMNS)}


class JournalFollower:
    """Follows ``REC.csv.journal.jsonl``: the events completed since the last call."""

    def __init__(self, path: str | Path):
        self._tail = _Tail(path)
        self.path = self._tail.path
        self.bad_lines = 0

    def poll(self) -> list[dict]:
        events: list[dict] = []
        for raw in self._tail.lines():
            if raw == b"\x00reset":
                return [{"event": "_reset"}]
            if not raw.strip():
                continue
            try:
                ev = json.loads(raw)
            except ValueError:
                self.bad_lines += 1
                continue
            if isinstance(ev, dict) and "event" in ev:
                events.append(ev)
        return events


_ESC = re.compile(rb"\\x([0-9a-fA-F]{2})")


class RawLogFollower:
    """Re-parses the received lines of ``REC.csv.raw.log`` to count dropped lines by cause.

    The acquisition's own parser counts are journalled only at the end of the run
    (``run_stop``); during the run this gives the same classification from the
    raw log (``sensor< …`` lines, escaped bytes restored).
    """

    def __init__(self, path: str | Path):
        self._tail = _Tail(path)
        self.path = self._tail.path
        self.parsers: dict[str, SentenceParser] = {}

    def poll(self) -> bool:
        lines = self._tail.lines()
        for raw in lines:
            if raw == b"\x00reset":
                self.parsers.clear()
                continue
            port, sep, rest = raw.partition(b"< ")
            frag = False
            if not sep:
                port, sep, rest = raw.partition(b"<~ ")
                frag = True
                if not sep:
                    continue  # a sent line (``port> …``) or noise
            name = port.decode("ascii", "replace")
            p = self.parsers.setdefault(name, SentenceParser())
            data = _ESC.sub(lambda m: bytes([int(m[1], 16)]), rest)
            p.feed(data if frag else data + b"\n")
        return bool(lines)

    def dropped(self) -> dict[str, dict[str, int]]:
        return {port: {k: v for k, v in p.stats.items() if v} for port, p in self.parsers.items()}


def journal_locked(path: str | Path) -> bool | None:
    """Whether a process holds the ``flock`` that an acquisition keeps on its journal while
    it runs (:class:`hw.journal.Journal`); ``None``: unknown (no journal, or no
    ``/proc/locks`` to read). Reads only: the writer's lock is never touched."""
    try:
        ino = os.stat(path).st_ino
        with open("/proc/locks", encoding="ascii", errors="replace") as f:
            text = f.read()
    except OSError:
        return None
    for line in text.splitlines():
        parts = line.split()  # id: FLOCK ADVISORY WRITE pid maj:min:inode start end
        if len(parts) >= 6 and parts[1] == "FLOCK" and parts[5].rsplit(":", 1)[-1] == str(ino):
            return True
    return False
