"""Drivers of the sensor and the platform over a :class:`~hw.linkio.Link`.

Each driver runs one reader thread on its port. Stream sentences (``GRV``,
``PLT``) go, in arrival order and numbered (``rx``), into an event queue that
may be shared by both drivers; replies (``GRA``/``PLA``) are matched to the
waiting query by sentence type and first field. A read failure puts a
:class:`LinkDown` into the queue and ends the thread (the owner reopens the
link and calls :meth:`start` again). Queries may come from any one thread at a
time; they never read the port themselves.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from hw.errors import DeviceError, LinkLost, ReplyTimeout
from hw.linkio import Clock, Link
from hw.nmea import Grv, Plt, Reply, Sentence, encode, format_number


@dataclass(frozen=True)
class Received:
    """A stream sentence as it arrived: port, receive number on that port, host time."""

    port: str
    rx: int
    t_mono: float
    sentence: Sentence


@dataclass(frozen=True)
class LinkDown:
    """The reader of ``port`` stopped on an error."""

    port: str
    error: LinkLost
    t_mono: float


@dataclass(frozen=True)
class SensorInfo:
    serial: str
    model: str
    firmware: str


@dataclass(frozen=True)
class PlatformInfo:
    serial: str
    firmware: str


class _Driver:
    QUERY = ""
    REPLY = ""

    def __init__(
        self,
        link: Link,
        *,
        events: queue.Queue | None = None,
        reply_timeout_s: float = 2.0,
        clock: Clock = time.monotonic,
    ):
        self.link = link
        self.events: queue.Queue = events if events is not None else queue.Queue()
        self.reply_timeout_s = reply_timeout_s
        self._clock = clock
        self._cond = threading.Condition()
        self._qlock = threading.Lock()
        self._replies: dict[str, tuple[int, Reply]] = {}
        self._rx = 0
        self.last_rx: float | None = None  # host time of the last valid sentence
        self.down: LinkLost | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    @property
    def name(self) -> str:
        return self.link.name

    @property
    def rx_count(self) -> int:
        """Sentences received so far on this port (the ``rx`` of the latest one)."""
        with self._cond:
            return self._rx

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        """Open the link if needed and start the reader thread."""
        self.stop()
        self.link.open()
        with self._cond:
            self.down = None
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._run, args=(self._stop,), name=f"hw-reader-{self.name}", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop the reader thread (the link stays open)."""
        t = self._thread
        if t is None:
            return
        self._stop.set()
        self.link.cancel_read()
        t.join(timeout=2.0)
        self._thread = None

    def close(self) -> None:
        self.stop()
        self.link.close()

    def _run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            try:
                sents = self.link.read_sentences()
            except LinkLost as e:
                if stop.is_set():
                    return
                with self._cond:
                    self.down = e
                    self._cond.notify_all()
                self.events.put(LinkDown(self.name, e, self._clock()))
                return
            if not sents:
                continue
            now = self._clock()
            with self._cond:
                for s in sents:
                    self._rx += 1
                    if s.type == self.REPLY and isinstance(s, Reply):
                        self._replies[s.key] = (self._rx, s)
                    else:
                        self.events.put(Received(self.name, self._rx, now, s))
                self.last_rx = now
                self._cond.notify_all()

    def query(
        self,
        key: str,
        *args: object,
        timeout_s: float | None = None,
        idle: Callable[[], None] | None = None,
    ) -> tuple[int, Reply]:
        """Send ``$<QUERY>,key,args…`` and wait for ``$<REPLY>,key,…``; returns ``(rx, reply)``.

        ``idle`` is called repeatedly while waiting (outside any lock), e.g. to keep
        writing samples. Raises :class:`ReplyTimeout` (nothing matched in time) or
        :class:`LinkLost`.
        """
        timeout = self.reply_timeout_s if timeout_s is None else timeout_s
        with self._qlock:
            with self._cond:
                self._replies.pop(key, None)
                if self.down is not None:
                    raise self.down
            if not self.running:
                raise LinkLost(self.name, "reader is not running")
            self.link.write(encode(self.QUERY, key, *args))
            deadline = self._clock() + timeout
            while True:
                with self._cond:
                    got = self._replies.pop(key, None)
                    if got is not None:
                        return got
                    if self.down is not None:
                        raise self.down
                    left = deadline - self._clock()
                    if left <= 0:
                        raise ReplyTimeout(self.name, ",".join([key, *map(str, args)]), timeout)
                    self._cond.wait(min(left, 0.01 if idle else 0.05))
                if idle is not None:
                    idle()

    def _checked(self, command: str, reply: Reply, min_args: int) -> Reply:
        if reply.is_error:
            reason = reply.fields[2] if len(reply.fields) > 2 else "unspecified"
            raise DeviceError(self.name, command, reason)
        if len(reply.args) < min_args:
            raise DeviceError(self.name, command, f"malformed reply {reply.fields!r}")
        return reply

    def next_event(self, timeout_s: float) -> Received | LinkDown | None:
        """The next stream event of a driver with its own queue (None on timeout)."""
        try:
            return self.events.get(timeout=timeout_s)
        except queue.Empty:
            return None


class SensorDriver(_Driver):
    """The gravity sensor: ``ID`` and ``RATE`` queries, a stream of ``GRV`` samples."""

    QUERY = "GRQ"
    REPLY = "GRA"

    def identify(self, *, idle: Callable[[], None] | None = None) -> SensorInfo:
        r = self._checked("ID", self.query("ID", idle=idle)[1], 3)
        return SensorInfo(serial=r.args[0], model=r.args[1], firmware=r.args[2])

    def rate(self, *, idle: Callable[[], None] | None = None) -> float:
        r = self._checked("RATE", self.query("RATE", idle=idle)[1], 1)
        try:
            hz = float(r.args[0])
        except ValueError:
            hz = float("nan")
        if not hz > 0 or hz == float("inf"):
            raise DeviceError(self.name, "RATE", f"bad rate {r.args[0]!r}")
        return hz

    def next_sample(self, timeout_s: float) -> Grv | None:
        """The next ``GRV`` (for a driver with its own queue); None on timeout."""
        deadline = self._clock() + timeout_s
        while (left := deadline - self._clock()) > 0:
            ev = self.next_event(left)
            if isinstance(ev, LinkDown):
                raise ev.error
            if ev is not None and isinstance(ev.sentence, Grv):
                return ev.sentence
        return None


class PlatformDriver(_Driver):
    """The gyro-platform: ``ID``, ``TILT x y``, ``LEVEL``; a stream of ``PLT`` status."""

    QUERY = "PLQ"
    REPLY = "PLA"

    def identify(self, *, idle: Callable[[], None] | None = None) -> PlatformInfo:
        r = self._checked("ID", self.query("ID", idle=idle)[1], 2)
        return PlatformInfo(serial=r.args[0], firmware=r.args[1])

    def tilt(
        self, x_arcsec: float, y_arcsec: float, *, idle: Callable[[], None] | None = None
    ) -> int:
        """Command a tilt; returns the reply's ``rx`` (later ``PLT`` have larger ``rx``).

        Raises :class:`DeviceError` on ``$PLA,TILT,ERR,<reason>``.
        """
        xs, ys = format_number(x_arcsec, 3), format_number(y_arcsec, 3)
        rx, r = self.query("TILT", xs, ys, idle=idle)
        self._checked(f"TILT {xs} {ys}", r, 1)
        return rx

    def level(self, *, idle: Callable[[], None] | None = None) -> int:
        """Level the platform (a tilt to 0, 0); returns the reply's ``rx``."""
        rx, r = self.query("LEVEL", idle=idle)
        self._checked("LEVEL", r, 1)
        return rx

    def next_status(self, timeout_s: float) -> tuple[int, Plt] | None:
        """The next ``(rx, PLT)`` (for a driver with its own queue); None on timeout."""
        deadline = self._clock() + timeout_s
        while (left := deadline - self._clock()) > 0:
            ev = self.next_event(left)
            if isinstance(ev, LinkDown):
                raise ev.error
            if ev is not None and isinstance(ev.sentence, Plt):
                return ev.rx, ev.sentence
        return None
