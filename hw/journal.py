"""Journal of an acquisition run: ``<record>.journal.jsonl``, one JSON object per event.

Every event is flushed and fsynced as it is written (events are rare: run
start, step start/hold/done, faults, gaps, reconnects, resume, run stop), so
after a crash the journal tells a resume where the run was. Each line has
``event``, ``utc`` (ISO 8601) and the event's fields. A torn last line (crash
mid-write) is skipped when reading.
"""

from __future__ import annotations

import fcntl
import json
import os
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

from chekan.errors import ChekanError
from chekan.files.durable import append_whole, fsync_dir


def utc_now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def journal_path(record_path: str | Path) -> Path:
    return Path(f"{record_path}.journal.jsonl")


def raw_log_path(record_path: str | Path) -> Path:
    return Path(f"{record_path}.raw.log")


class Journal:
    """Append-only, fsynced-per-event JSON-lines journal (``flock``-ed while open)."""

    def __init__(self, path: str | Path, *, utc: Callable[[], str] = utc_now):
        self.path = Path(path)
        self._utc = utc
        new = not self.path.exists()
        self._f = open(self.path, "ab", buffering=0)
        try:  # one runner per record: a second one (e.g. a resume) fails at once
            fcntl.flock(self._f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._f.close()
            raise ChekanError(
                f"{self.path} is locked: another acquisition is writing this record"
            ) from None
        if new:
            fsync_dir(self.path)  # the new name survives a crash
        else:
            self._cut_torn_tail()
        self._good = os.fstat(self._f.fileno()).st_size

    def _cut_torn_tail(self) -> None:
        raw = self.path.read_bytes()
        if raw and not raw.endswith(b"\n"):
            with open(self.path, "r+b") as f:
                f.truncate(raw.rfind(b"\n") + 1)
                f.flush()
                os.fsync(f.fileno())

    def write(self, event: str, **fields: object) -> dict:
        """Append one event, whole and fsynced; a failed write (``OSError``) leaves no part
        of it behind, so a later event may still be written."""
        rec = {"event": event, "utc": self._utc(), **fields}
        line = json.dumps(rec, ensure_ascii=False, default=str) + "\n"
        good = append_whole(self._f, line.encode("utf-8"), self._good)
        try:
            os.fsync(self._f.fileno())
        except OSError:
            os.ftruncate(self._f.fileno(), self._good)
            raise
        self._good = good
        return rec

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_journal(path: str | Path) -> list[dict]:
    """All complete events of a journal (a torn or unreadable last line is skipped)."""
    events: list[dict] = []
    lines = Path(path).read_text(encoding="utf-8", errors="replace").split("\n")
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            ev = json.loads(line)
        except json.JSONDecodeError:
            if i >= len(lines) - 2:  # the last (possibly torn) line
                continue
            raise ValueError(f"{path}:{i + 1}: not a JSON journal line") from None
        if isinstance(ev, dict) and "event" in ev:
            events.append(ev)
    return events
