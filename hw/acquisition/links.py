"""Link supervision: both ports open, watched for silence and errors, reopened with back-off.

Silence longer than ``timeout_s`` (or a read error) closes and reopens the port by its
URL with back-off, up to ``give_up_s`` without data (:class:`~hw.errors.GaveUp`).
Queries are retried through reconnects and lost replies (:meth:`LinkSupervisor.call`).
"""

from __future__ import annotations

import queue
from collections.abc import Callable
from typing import TypeVar

from hw.acquisition.plan import Options
from hw.acquisition.recorder import EventLog
from hw.acquisition.summary import PORTS
from hw.drivers import LinkDown, PlatformDriver, Received, SensorDriver
from hw.errors import GaveUp, LinkLost, ReplyTimeout
from hw.events import Event
from hw.linkio import Backoff, Link, RawLog, reopen

T = TypeVar("T")
Driver = SensorDriver | PlatformDriver
WATCH_INTERVAL_S = 0.05


class LinkSupervisor:
    """Owns both drivers, their event queue and the reconnect counts of a session."""

    def __init__(
        self,
        opts: Options,
        journal: EventLog,
        t_last: Callable[[], float | None],
        *,
        clock: Callable[[], float],
        sleep: Callable[[float], None],
    ):
        self.opts = opts
        self._journal = journal
        self._t_last = t_last
        self._clock = clock
        self._sleep = sleep
        self.events: queue.Queue[Received | LinkDown] = queue.Queue()
        self.sensor: SensorDriver | None = None
        self.platform: PlatformDriver | None = None
        self.reconnects: dict[str, int] = dict.fromkeys(PORTS, 0)
        self.watching = True
        self._last_watch = 0.0
        self._started = clock()

    def drivers(self) -> dict[str, Driver | None]:
        """The drivers by port name (None before :meth:`open`)."""
        return {"sensor": self.sensor, "platform": self.platform}

    def open(self, raw: RawLog) -> None:
        """Open both ports (a port that fails to open is reopened with back-off)."""
        o, clock = self.opts, self._clock

        def link(url: str, name: str) -> Link:
            return Link(url, name, read_timeout_s=o.read_timeout_s, raw_log=raw, clock=clock)

        timeout = o.reply_timeout_s
        self.sensor = SensorDriver(
            link(o.sensor_url, "sensor"), events=self.events, reply_timeout_s=timeout, clock=clock
        )
        self.platform = PlatformDriver(
            link(o.platform_url, "platform"),
            events=self.events,
            reply_timeout_s=timeout,
            clock=clock,
        )
        for port, drv in self.drivers().items():
            assert drv is not None
            try:
                drv.start()
            except LinkLost as e:
                self.reconnect(port, str(e), first=True)

    def reconnect(self, port: str, reason: str, first: bool = False) -> None:
        """Close ``port`` and reopen it with back-off; GaveUp after ``give_up_s`` without data."""
        drv = self.drivers()[port]
        assert drv is not None
        drv.stop()
        since = drv.last_rx if drv.last_rx is not None else self._started
        self._journal(Event.LINK_LOST, port=port, reason=reason, t_s=self._t_last())
        if self._clock() - since > self.opts.give_up_s:  # it reopens but stays silent
            raise GaveUp(port, self._clock() - since, drv.link.opens, reason)
        attempts = reopen(
            drv.link,
            give_up_at=since + self.opts.give_up_s,
            backoff=Backoff(self.opts.backoff_initial_s, 2.0, self.opts.backoff_max_s),
            clock=self._clock,
            sleep=self._sleep,
            down_since=since,
        )
        drv.start()
        if not first:
            self.reconnects[port] += 1
        self._journal(
            Event.RECONNECT,
            port=port,
            attempts=attempts,
            down_s=round(self._clock() - since, 3),
            t_s=self._t_last(),
        )

    def watch(self, force: bool = False) -> None:
        """Reconnect a port that is down, stopped or silent (at most every 50 ms unless forced)."""
        now = self._clock()
        if not self.watching or (not force and now - self._last_watch < WATCH_INTERVAL_S):
            return
        self._last_watch = now
        for port, drv in self.drivers().items():
            assert drv is not None
            last = max(drv.last_rx or 0.0, drv.link.opened_at or 0.0)
            if drv.down is not None:
                self.reconnect(port, drv.down.reason)
            elif not drv.running:
                self.reconnect(port, "reader stopped")
            elif now - last > self.opts.timeout_s:
                self.reconnect(port, f"silent for {now - last:.1f} s")

    def call(
        self,
        port: str,
        fn: Callable[[], T],
        what: str,
        accepted: Callable[[], T | None] | None = None,
    ) -> T:
        """Run a query with retries: reopen on LinkLost, retry on timeout, until give-up.

        ``accepted`` (after a timeout) returns a result if the device evidently obeyed
        although its reply was lost; the command is then not sent again.
        """
        start = self._clock()
        while True:
            try:
                return fn()
            except LinkLost as e:
                self.reconnect(port, e.reason)
            except ReplyTimeout as e:
                self._journal(Event.REPLY_TIMEOUT, port=port, query=what, t_s=self._t_last())
                if accepted is not None and (got := accepted()) is not None:
                    self._journal(Event.REPLY_LOST_COMMAND_OBEYED, port=port, query=what)
                    return got
                if self._clock() - start > self.opts.give_up_s:
                    raise GaveUp(port, self._clock() - start, 0, str(e)) from None
                self.watch(force=True)

    def revive_platform(self, within_s: float) -> PlatformDriver:
        """The platform driver, reopened first if it is down (for levelling at the end)."""
        drv = self.platform
        assert drv is not None
        if drv.down is not None or not drv.running:
            drv.stop()
            reopen(
                drv.link,
                give_up_at=self._clock() + within_s,
                clock=self._clock,
                sleep=self._sleep,
            )
            drv.start()
        return drv

    def close(self) -> dict[str, dict[str, int]]:
        """Close both ports; returns the parser's dropped-line counts of each opened one."""
        dropped: dict[str, dict[str, int]] = {}
        for port, drv in self.drivers().items():
            if drv is not None:
                drv.close()
                dropped[port] = dict(drv.link.parser.stats)
        return dropped
