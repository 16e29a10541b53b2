"""One serial port by pyserial URL: open, framed reading, raw log, reopen with back-off.

Reading never uses ``readline()`` (it returns partial lines on timeout): bytes
come from ``read(in_waiting or 1)`` into a :class:`~hw.nmea.SentenceParser`.
Any pyserial URL works (``/dev/ttyUSB0``, ``/dev/pts/7``, a stable symlink,
``socket://host:port``, ``loop://``, ``spy://…``, and the in-process emulator's
``chekanemu://sensor?session=NAME``). Plain device paths are opened with
``exclusive=True`` (an advisory ``flock``: a second acquisition on the same port
fails at once instead of stealing bytes).

Clocks are injected: ``clock`` is monotonic seconds (timeouts, back-off),
``sleep`` waits; tests pass fakes instead of patching :mod:`time`.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import serial

from chekan.files.durable import append_whole
from hw.errors import GaveUp, LinkLost
from hw.nmea import HOST_TYPES, Parser, Sentence, SentenceParser

if "hw" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("hw")  # chekanemu:// (hw/protocol_chekanemu.py)

BAUDRATE = 115200
_EXCLUSIVE_SCHEMES = ("", "spy", "chekanemu")  # schemes whose Serial honours exclusive=True

Clock = Callable[[], float]


def url_scheme(url: str) -> str:
    """``"socket"`` for ``socket://…``; ``""`` for a device path."""
    return url.split("://", 1)[0].lower() if "://" in url else ""


def open_port(url: str, *, timeout_s: float = 0.05, write_timeout_s: float = 2.0):
    """Open ``url`` with the protocol's settings (115200 8N1); exclusive where supported."""
    kw: dict = dict(baudrate=BAUDRATE, timeout=timeout_s, write_timeout=write_timeout_s)
    if url_scheme(url) in _EXCLUSIVE_SCHEMES:
        kw["exclusive"] = True
    return serial.serial_for_url(url, **kw)


_CR = b"\r"
_CRLF = b"\r\n"


def _escape(line: bytes) -> str:
    return line.decode("latin-1").encode("unicode_escape").decode("ascii")


class RawLog:
    """Every received line (and every sent one), prefixed by port and direction.

    Lines look like ``sensor< $GRV,…*4A`` and ``platform> $PLQ,TILT,…*1C``; bytes
    that are not printable ASCII are escaped (``\\xNN``) so the log stays text and
    can be re-parsed. Written at most every ``flush_interval_s`` and on close, whole
    lines only. A write that fails (a full disk) is cut back to the last whole line and
    ends the log: the reader threads that feed it never raise; :attr:`error` holds the
    failure for the acquisition to act on.
    """

    def __init__(
        self, path: str | Path, *, flush_interval_s: float = 0.5, clock: Clock = time.monotonic
    ):
        self.path = str(path)
        self._f = open(self.path, "ab", buffering=0)
        self._good = os.fstat(self._f.fileno()).st_size
        self._pending: list[str] = []
        self._lock = threading.Lock()
        self._partial: dict[str, bytearray] = {}
        self._clock = clock
        self._flush_interval_s = flush_interval_s
        self._last_flush = clock()
        self.error: OSError | None = None

    def _write(self, text: str, force: bool = False) -> None:
        if self._f.closed or self.error is not None:
            return
        self._pending.append(text)
        now = self._clock()
        if force or now - self._last_flush >= self._flush_interval_s:
            self._last_flush = now
            data, self._pending = "".join(self._pending).encode("ascii"), []
            try:
                self._good = append_whole(self._f, data, self._good)
            except OSError as e:
                self.error = e

    def received(self, port: str, data: bytes) -> None:
        with self._lock:
            buf = self._partial.setdefault(port, bytearray())
            buf += data
            *lines, rest = bytes(buf).split(b"\n")
            out = [f"{port}< {_escape(ln.removesuffix(_CR))}\n" for ln in lines]
            if len(rest) > 1024:  # no end of line in sight: log it as a fragment
                out.append(f"{port}<~ {_escape(rest)}\n")
                rest = b""
            buf[:] = rest
            if out:
                self._write("".join(out))

    def sent(self, port: str, line: bytes) -> None:
        with self._lock:
            self._write(f"{port}> {_escape(line.rstrip(_CRLF))}\n")

    def note(self, port: str, text: str) -> None:
        """A host event in the byte stream's context (open, close, reconnect)."""
        with self._lock:
            self._write(f"{port}# {text}\n")

    def close(self) -> None:
        with self._lock:
            tail = [
                f"{port}<~ {_escape(bytes(buf))}\n" for port, buf in self._partial.items() if buf
            ]
            self._partial.clear()
            self._write("".join(tail), force=True)
            if not self._f.closed:
                self._f.close()


class Link:
    """One port: ``open``/``close``, ``write``, ``read_sentences`` (raises :class:`LinkLost`).

    The parser (and its drop counters) lives as long as the link; a partial
    sentence pending at a reopen is counted as torn.
    """

    def __init__(
        self,
        url: str,
        name: str,
        *,
        read_timeout_s: float = 0.05,
        write_timeout_s: float = 2.0,
        types: Mapping[str, Parser] = HOST_TYPES,
        raw_log: RawLog | None = None,
        opener: Callable[..., object] = open_port,
        clock: Clock = time.monotonic,
    ):
        self.url = url
        self.name = name
        self.read_timeout_s = read_timeout_s
        self.write_timeout_s = write_timeout_s
        self.parser = SentenceParser(types)
        self.raw_log = raw_log
        self._opener = opener
        self._clock = clock
        self._ser: Any = None  # the open serial port (pyserial or an emulator)
        self._wlock = threading.Lock()
        self.opened_at: float | None = None
        self.opens = 0

    @property
    def is_open(self) -> bool:
        return self._ser is not None

    def open(self) -> None:
        """Open the port (by path: a replugged device reappears under its stable name)."""
        if self._ser is not None:
            return
        try:
            self._ser = self._opener(
                self.url, timeout_s=self.read_timeout_s, write_timeout_s=self.write_timeout_s
            )
        except (serial.SerialException, OSError, ValueError) as e:
            raise LinkLost(self.name, f"cannot open {self.url}: {e}") from None
        self.parser.reset()
        self.opened_at = self._clock()
        self.opens += 1
        if self.raw_log:
            self.raw_log.note(self.name, f"open {self.url}")

    def close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except (serial.SerialException, OSError):
                pass
            if self.raw_log:
                self.raw_log.note(self.name, "close")

    def cancel_read(self) -> None:
        """Wake a reader blocked in ``read`` (where the port class supports it)."""
        ser = self._ser
        if ser is not None and hasattr(ser, "cancel_read"):
            try:
                ser.cancel_read()
            except (serial.SerialException, OSError, AttributeError):
                pass

    def write(self, data: bytes) -> None:
        """Send bytes (one or more complete sentences)."""
        with self._wlock:
            ser = self._ser
            if ser is None:
                raise LinkLost(self.name, "port is closed")
            try:
                ser.write(data)
            except (serial.SerialException, OSError) as e:
                raise LinkLost(self.name, f"write failed: {e}") from None
        if self.raw_log:
            for line in data.split(b"\n"):
                if line:
                    self.raw_log.sent(self.name, line)

    def read_sentences(self) -> list[Sentence]:
        """Wait up to ``read_timeout_s`` for bytes; return the sentences they complete."""
        ser = self._ser
        if ser is None:
            raise LinkLost(self.name, "port is closed")
        try:
            n = ser.in_waiting
            data = ser.read(n or 1)
            if data and n == 0:
                more = ser.in_waiting
                if more:
                    data += ser.read(more)
        except (serial.SerialException, OSError, TypeError, AttributeError) as e:
            # TypeError/AttributeError: pyserial internals after a concurrent close
            raise LinkLost(self.name, f"read failed: {e}") from None
        if not data:
            return []
        if self.raw_log:
            self.raw_log.received(self.name, data)
        return self.parser.feed(data)


class Backoff:
    """Delays ``initial, initial·factor, …`` capped at ``maximum``."""

    def __init__(self, initial: float = 0.1, factor: float = 2.0, maximum: float = 5.0):
        self.initial, self.factor, self.maximum = initial, factor, maximum
        self._next = initial

    def next(self) -> float:
        d = self._next
        self._next = min(self._next * self.factor, self.maximum)
        return d


def reopen(
    link: Link,
    *,
    give_up_at: float,
    backoff: Backoff | None = None,
    clock: Clock = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    on_attempt: Callable[[int, str], None] | None = None,
    down_since: float | None = None,
) -> int:
    """Close and reopen ``link`` by its URL with back-off; return the number of attempts.

    Raises :class:`GaveUp` once ``clock()`` passes ``give_up_at``.
    """
    backoff = backoff or Backoff()
    link.close()
    attempts = 0
    last = ""
    started = clock() if down_since is None else down_since
    while True:
        delay = backoff.next()
        now = clock()
        if now + delay > give_up_at:
            delay = max(0.0, give_up_at - now)
        sleep(delay)
        attempts += 1
        try:
            link.open()
            return attempts
        except LinkLost as e:
            last = e.reason
            if on_attempt:
                on_attempt(attempts, last)
        if clock() >= give_up_at:
            raise GaveUp(link.name, clock() - started, attempts, last)
