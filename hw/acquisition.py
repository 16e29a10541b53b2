"""The acquisition runner: a tilt program on the platform, every sensor sample to a record.

For each program step it sends ``TILT``, waits for a ``HOLD`` at the target
(reported after the command's reply, within ``angle_tol_arcsec``), then counts
the dwell in SENSOR SAMPLES: ``round(dwell_s × rate)`` sample periods from the
first sample after the hold, on the sample clock (``t_s`` comes from ``seq``
through its wrap; a jump in ``seq`` is a gap and ``t_s`` jumps with it, so a
step's rows number ``dwell × rate`` minus the samples lost in gaps). Every
sample is recorded, also while the platform moves (``step`` empty), with the
latest platform angles (empty when no ``PLT`` came for ``stale_s``). The record
starts with the first sample after the first ``PLT``; the first row of each
session (new or resumed) never belongs to a dwell, so a resumed step's new run
is always a separate contiguous run. A dwell is not extended or repeated for
samples lost in gaps (they are counted, journaled and in the summary).

Files next to the record ``rec.csv``:

- ``rec.csv`` — :class:`chekan.records.RecordWriter` (flush per line, fsync every
  ``fsync_interval_s``);
- ``rec.csv.journal.jsonl`` — :mod:`hw.journal`, fsynced per event;
- ``rec.csv.raw.log`` — every received (and sent) line with its port.

Faults: silence longer than ``timeout_s`` (or a read error) closes and reopens
the port by its URL with back-off, up to ``give_up_s`` without data
(:class:`~hw.errors.GaveUp`, exit 3). A platform ``FAULT`` re-sends the step's
``TILT`` (again every ``recommand_s`` while it lasts) and restarts the step's
dwell at the next ``HOLD`` (the interrupted run stays in the record: analysis
uses the last complete run of a step). ``TILT,ERR`` stops the run (exit 1).
At the end, on an error and on Ctrl-C (exit 130) the platform is levelled.

:func:`resume` continues a killed or interrupted run from its journal and
record: completed steps are kept; the first unfinished step is re-run from its
``TILT`` (its partial rows stay); ``t_s`` continues strictly after the last
complete row, through ``seq`` (the journal keeps the ``seq`` ↔ ``t_s`` anchor).
"""

from __future__ import annotations

import math
import queue
import re
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from chekan.errors import ChekanError
from chekan.program import TiltProgram
from chekan.records import RecordWriter, read_record
from hw.drivers import LinkDown, PlatformDriver, Received, SensorDriver
from hw.errors import DeviceError, GaveUp, HwError, LinkLost, ReplyTimeout
from hw.journal import Journal, journal_path, raw_log_path, read_journal
from hw.linkio import Backoff, Link, RawLog, reopen
from hw.nmea import REASONS, SEQ_MOD, Grv, Plt
from hw.progress import Progress

EXIT_OK = 0
EXIT_DEVICE = 1  # the device refused (TILT,ERR) or misbehaved; or an I/O error
EXIT_CONFIG = 2  # bad arguments, existing record, wrong instrument on resume
EXIT_GAVE_UP = 3  # a link stayed down
EXIT_INTERRUPTED = 130
BACKWARDS_WINDOW = 64  # a seq this close behind the last one is a stale line, not a 65 k gap
PORTS = ("sensor", "platform")
PROTECTED_META = ("format", "serial", "platform_serial", "sample_rate_hz", "started")


@dataclass(frozen=True)
class PlanStep:
    """One program step as the runner needs it (also stored in the journal)."""

    index: int
    round: int
    kind: str
    label: str
    x_arcsec: float
    y_arcsec: float
    dwell_s: float
    settle_s: float

    @classmethod
    def from_json(cls, d: dict) -> PlanStep:
        return cls(**{f.name: d[f.name] for f in fields(cls)})


def plan_from_program(program: TiltProgram) -> list[PlanStep]:
    return [
        PlanStep(
            s.index,
            s.round,
            s.kind,
            s.label(),
            float(s.tilt_x_arcsec),
            float(s.tilt_y_arcsec),
            float(s.dwell_s),
            float(s.settle_s),
        )
        for s in program.steps
    ]


@dataclass
class Options:
    """Settings of a run. Host-time limits are in wall seconds, the rest in sample-clock seconds."""

    sensor_url: str = ""
    platform_url: str = ""
    timeout_s: float = 5.0  # host: silence on a port -> reopen it
    give_up_s: float = 120.0  # host: no data that long -> give up
    reply_timeout_s: float = 2.0  # host: one query's wait for its reply
    hold_timeout_s: float = 900.0  # sample clock: TILT to HOLD (re-sent once, then an error)
    recommand_s: float = 10.0  # sample clock: TILT re-sent this often while FAULT lasts
    angle_tol_arcsec: float = 60.0  # a HOLD counts if this close to the commanded angles
    stale_s: float = 5.0  # sample clock and host: older platform angles are not written
    fsync_interval_s: float = 2.0  # host
    level_wait_s: float = 60.0  # host: wait for the level HOLD at the end
    read_timeout_s: float = 0.05
    backoff_initial_s: float = 0.1
    backoff_max_s: float = 5.0

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> Options:
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


@dataclass
class Summary:
    status: str = "running"
    exit_code: int = 0
    message: str = ""
    samples: int = 0  # rows written in this session
    gaps: int = 0  # seq jumps
    lost_samples: int = 0  # samples missing in those jumps
    duplicates: int = 0
    out_of_order: int = 0
    saturated: int = 0
    therm: int = 0
    faults: int = 0  # platform FAULT episodes
    recommands: int = 0  # TILT re-sent (FAULT, hold timeout)
    hold_restarts: int = 0  # dwells restarted after the hold was lost
    reconnects: dict[str, int] = field(default_factory=lambda: dict.fromkeys(PORTS, 0))
    dropped: dict[str, dict[str, int]] = field(
        default_factory=lambda: {p: dict.fromkeys(REASONS, 0) for p in PORTS}
    )
    steps_done: int = 0
    n_steps: int = 0
    t_s_first: float | None = None
    t_s_last: float | None = None
    levelled: bool = False

    def format(self) -> str:
        lines = [
            f"acquisition {self.status} (exit {self.exit_code})"
            + (f": {self.message}" if self.message else ""),
            f"  steps      {self.steps_done}/{self.n_steps} done",
            f"  samples    {self.samples} rows written"
            + (
                f", t_s {self.t_s_first:g} … {self.t_s_last:g}"
                if self.t_s_first is not None and self.t_s_last is not None
                else ""
            ),
            f"  gaps       {self.gaps} ({self.lost_samples} samples lost), "
            f"{self.duplicates} duplicate and {self.out_of_order} stale lines ignored",
            f"  platform   {self.faults} FAULT, {self.recommands} TILT re-sent, "
            f"{self.hold_restarts} dwell(s) restarted, "
            f"levelled: {'yes' if self.levelled else 'NO'}",
            "  reconnects " + ", ".join(f"{p} {n}" for p, n in self.reconnects.items()),
        ]
        for p, d in self.dropped.items():
            items = ", ".join(f"{k} {v}" for k, v in d.items() if v)
            lines.append(f"  dropped    {p}: {items or 'none'}")
        if self.saturated or self.therm:
            lines.append(f"  flagged    {self.saturated} SAT, {self.therm} THERM samples")
        return "\n".join(lines)


@dataclass
class ResumeState:
    first_step: int
    done: set[int]
    last_idx: int | None  # sample index of the last complete row
    last_seq: int | None  # its seq
    rate_hz: float
    serial: str


def _utc_stamp() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


class Acquisition:
    """One run (new or resumed) of a plan; :meth:`run` returns its :class:`Summary`."""

    def __init__(
        self,
        record_path: str | Path,
        plan: list[PlanStep],
        options: Options,
        *,
        program_name: str = "custom",
        meta: dict[str, str] | None = None,
        resume_state: ResumeState | None = None,
        progress: Callable[[Progress], None] | None = None,
        report: Callable[[str], None] | None = print,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        utc: Callable[[], str] | None = None,
    ):
        self.path = Path(record_path)
        self._utc = utc or _utc_stamp
        self.plan = plan
        self.opts = options
        self.program_name = program_name
        self.meta = dict(meta or {})
        self.resume_state = resume_state
        self.progress = progress
        self.report = report
        self._clock = clock
        self._sleep = sleep
        self.summary = Summary(n_steps=len(plan))
        self.events: queue.Queue = queue.Queue()
        self.rate = 1.0
        self.sensor: SensorDriver | None = None
        self.platform: PlatformDriver | None = None
        self.journal: Journal | None = None
        self.raw: RawLog | None = None
        self.writer: RecordWriter | None = None
        self._rows: list[tuple[float, ...]] = []  # rows of the current pump cycle
        self.sensor_info = None
        self.platform_info = None
        # sample clock
        self._last_seq: int | None = None
        self._last_idx: int | None = None
        # platform
        self._angles: tuple[float, float] | None = None
        self._since_plt = 10**9
        self._plt_mono = -1e18
        self._plt_state = ""
        self._plt_rx = 0
        self._sensor_status = "OK"
        # step state machine
        self._phase = "idle"  # idle | wait_hold | hold_pending | dwell | done | leveling | level
        self._step: PlanStep | None = None
        self._target = (0.0, 0.0)
        self._tilt_rx = 0
        self._cmd_idx: int | None = None
        self._cmd_mono = 0.0
        self._hold_retry = False
        self._last_recommand_idx: int | None = None
        self._dwell_start = 0
        self._dwell_n = 0
        self._dwell_rows = 0
        self._commanding = False
        self._closing = False
        self._last_watch = 0.0
        self._last_progress = 0.0
        self._started_mono = clock()

    # ------------------------------------------------------------------ helpers
    def _j(self, event: str, **kw) -> None:
        self._flush_rows()  # the record is never behind its journal
        if self.journal is not None:
            self.journal.write(event, **kw)

    def _flush_rows(self) -> None:
        """Write the rows of this pump cycle (one write and flush per batch)."""
        if self._rows and self.writer is not None:
            rows, self._rows = self._rows, []
            self.writer.write_rows(*(list(c) for c in zip(*rows, strict=True)))

    @property
    def _t_last(self) -> float | None:
        return None if self._last_idx is None else self._last_idx / self.rate

    def _drivers(self) -> dict[str, SensorDriver | PlatformDriver]:
        return {"sensor": self.sensor, "platform": self.platform}

    # ------------------------------------------------------------------ links
    def _open(self) -> None:
        self.raw = RawLog(raw_log_path(self.path), clock=self._clock)
        mk = dict(read_timeout_s=self.opts.read_timeout_s, raw_log=self.raw, clock=self._clock)
        common = dict(
            events=self.events, reply_timeout_s=self.opts.reply_timeout_s, clock=self._clock
        )
        self.sensor = SensorDriver(Link(self.opts.sensor_url, "sensor", **mk), **common)
        self.platform = PlatformDriver(Link(self.opts.platform_url, "platform", **mk), **common)
        for port, drv in self._drivers().items():
            try:
                drv.start()
            except LinkLost as e:
                self._reconnect(port, str(e), first=True)

    def _reconnect(self, port: str, reason: str, first: bool = False) -> None:
        drv = self._drivers()[port]
        drv.stop()
        since = drv.last_rx if drv.last_rx is not None else self._started_mono
        self._j("link_lost", port=port, reason=reason, t_s=self._t_last)
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
            self.summary.reconnects[port] += 1
        self._j(
            "reconnect",
            port=port,
            attempts=attempts,
            down_s=round(self._clock() - since, 3),
            t_s=self._t_last,
        )

    def _watch_links(self, force: bool = False) -> None:
        now = self._clock()
        if self._closing or (not force and now - self._last_watch < 0.05):
            return
        self._last_watch = now
        for port, drv in self._drivers().items():
            last = max(drv.last_rx or 0.0, drv.link.opened_at or 0.0)
            if drv.down is not None:
                self._reconnect(port, drv.down.reason)
            elif not drv.running:
                self._reconnect(port, "reader stopped")
            elif now - last > self.opts.timeout_s:
                self._reconnect(port, f"silent for {now - last:.1f} s")

    def _call(
        self,
        port: str,
        fn: Callable[[], object],
        what: str,
        accepted: Callable[[], object | None] | None = None,
    ) -> object:
        """Run a query with retries: reopen on LinkLost, retry on timeout, until give-up.

        ``accepted`` (after a timeout) returns a result if the device evidently obeyed
        although its reply was lost; the command is then not sent again.
        """
        start = self._clock()
        while True:
            try:
                return fn()
            except LinkLost as e:
                self._reconnect(port, e.reason)
            except ReplyTimeout as e:
                self._j("reply_timeout", port=port, query=what, t_s=self._t_last)
                if accepted is not None and (got := accepted()) is not None:
                    self._j("reply_lost_command_obeyed", port=port, query=what)
                    return got
                if self._clock() - start > self.opts.give_up_s:
                    raise GaveUp(port, self._clock() - start, 0, str(e)) from None
                self._watch_links(force=True)

    # ------------------------------------------------------------------ events
    def _pump(self, timeout: float = 0.05, watch: bool = True) -> None:
        """Handle queued events (waiting up to ``timeout`` for the first), then watch links."""
        try:
            ev = self.events.get(timeout=timeout)
        except queue.Empty:
            ev = None
        n = 0
        while ev is not None:
            self._handle(ev)
            n += 1
            if n >= 200:
                break
            try:
                ev = self.events.get_nowait()
            except queue.Empty:
                ev = None
        self._flush_rows()
        if watch and not self._commanding:
            self._watch_links()

    def _idle(self) -> None:
        """While a query waits: keep recording (no commands, no reconnects)."""
        self._pump(timeout=0.0, watch=False)

    def _handle(self, ev: Received | LinkDown) -> None:
        if isinstance(ev, LinkDown):
            return  # the driver's ``down`` is seen by _watch_links
        s = ev.sentence
        if isinstance(s, Grv):
            self._on_sample(s, ev.t_mono)
        elif isinstance(s, Plt):
            self._on_status(ev.rx, s)

    # ------------------------------------------------------------------ samples
    def _index(self, seq: int) -> int | None:
        """Sample index of ``seq`` on the sample clock; None for a duplicate or stale line."""
        s = self.summary
        if self._last_seq is None:
            rs = self.resume_state
            if rs is not None and rs.last_idx is not None and rs.last_seq is None:
                idx = rs.last_idx + 1  # no seq anchor in the journal: continue right after
            elif rs is not None and rs.last_idx is not None and rs.last_seq is not None:
                d = (seq - rs.last_seq) % SEQ_MOD
                if d == 0:
                    s.duplicates += 1
                    return None
                idx = rs.last_idx + d
                if d > 1:
                    s.gaps += 1
                    s.lost_samples += d - 1
                    self._j(
                        "gap",
                        seq_from=rs.last_seq,
                        seq_to=seq,
                        lost=d - 1,
                        t_s_from=rs.last_idx / self.rate,
                        t_s_to=idx / self.rate,
                        step=None,
                        resumed=True,
                    )
            else:
                idx = 0
            self._last_seq, self._last_idx = seq, idx
            self._j("sync", seq_ref=seq, t_ref=idx / self.rate, resumed=rs is not None)
            return idx
        d = (seq - self._last_seq) % SEQ_MOD
        if d == 0:
            s.duplicates += 1
            return None
        if d > SEQ_MOD - BACKWARDS_WINDOW:
            s.out_of_order += 1
            return None
        idx = self._last_idx + d
        if d > 1:
            s.gaps += 1
            s.lost_samples += d - 1
            self._j(
                "gap",
                seq_from=self._last_seq,
                seq_to=seq,
                lost=d - 1,
                t_s_from=self._last_idx / self.rate,
                t_s_to=idx / self.rate,
                step=self._step.index if self._step else None,
            )
        self._last_seq, self._last_idx = seq, idx
        return idx

    def _on_sample(self, g: Grv, t_mono: float) -> None:
        if self.writer is None or (self._last_seq is None and self._angles is None):
            return  # the record starts with the first sample after a platform status
        idx = self._index(g.seq)
        if idx is None:
            return
        step = None
        first_row = self.summary.samples == 0  # never part of a dwell: on resume it separates
        if self._phase == "hold_pending" and not self._commanding and not first_row:
            self._phase = "dwell"
            self._dwell_start = idx
            self._dwell_rows = 0
            self._j("hold", step=self._step.index, t_s=idx / self.rate, angles=self._angles)
        if self._phase == "dwell" and idx < self._dwell_start + self._dwell_n:
            step = self._step.index
            self._dwell_rows += 1
        self._since_plt += 1
        stale = (
            self._since_plt > self.opts.stale_s * self.rate
            and self._clock() - self._plt_mono > self.opts.stale_s
        )  # old on the sample clock AND in host time (an accelerated emulator's ports skew)
        ang = None if stale else self._angles
        t = idx / self.rate
        nan = math.nan
        self._rows.append(
            (
                t,
                nan if g.m1 is None else g.m1,
                nan if g.m2 is None else g.m2,
                ang[0] if ang else nan,
                ang[1] if ang else nan,
                nan if step is None else step,
                nan if g.temp is None else g.temp,
            )
        )
        s = self.summary
        s.samples += 1
        if s.t_s_first is None:
            s.t_s_first = t
        s.t_s_last = t
        if g.status == "SAT":
            s.saturated += 1
        elif g.status == "THERM":
            s.therm += 1
        if g.status != self._sensor_status:  # episodes of SAT / THERM go to the journal
            self._j("sensor_status", status=g.status, was=self._sensor_status or None, t_s=t)
            self._sensor_status = g.status
        if self._cmd_idx is None and t_mono >= self._cmd_mono:
            self._cmd_idx = idx  # the first sample received after the command's reply
        if not self._commanding:
            self._after_sample(idx)
        self._show()

    def _after_sample(self, idx: int) -> None:
        st = self._step
        if self._phase == "dwell" and idx >= self._dwell_start + self._dwell_n - 1:
            self._phase = "done"
            self._j(
                "step_done",
                step=st.index,
                t_s_first=self._dwell_start / self.rate,
                t_s_last=min(idx, self._dwell_start + self._dwell_n - 1) / self.rate,
                samples=self._dwell_rows,
                lost=self._dwell_n - self._dwell_rows,
            )
        elif self._phase == "wait_hold" and st is not None and self._cmd_idx is not None:
            waited = idx - self._cmd_idx
            if waited > self.opts.hold_timeout_s * self.rate:
                if self._hold_retry:
                    raise DeviceError(
                        "platform",
                        f"TILT {st.x_arcsec:g} {st.y_arcsec:g}",
                        f"no HOLD at the target within {self.opts.hold_timeout_s:g} s of "
                        f"sample clock (state {self._plt_state or '?'}, angles {self._angles})",
                    )
                self._hold_retry = True
                self.summary.recommands += 1
                self._j("hold_timeout", step=st.index, t_s=idx / self.rate)
                self._send_tilt("hold timeout")

    # ------------------------------------------------------------------ platform
    def _near_target(self, p: Plt) -> bool:
        tol = self.opts.angle_tol_arcsec
        return abs(p.x - self._target[0]) <= tol and abs(p.y - self._target[1]) <= tol

    def _angles_near_target(self) -> bool:
        a, tol = self._angles, self.opts.angle_tol_arcsec
        return (
            a is not None and max(abs(a[0] - self._target[0]), abs(a[1] - self._target[1])) <= tol
        )

    def _on_status(self, rx: int, p: Plt) -> None:
        prev = self._plt_state
        self._angles = (p.x, p.y)
        self._plt_rx = rx
        self._since_plt = 0
        self._plt_mono = self._clock()
        self._plt_state = p.state
        if self._commanding or rx <= self._tilt_rx:
            return  # sent before the platform saw our last command
        if self._phase == "leveling":
            if p.state == "HOLD" and self._near_target(p):
                self._phase = "level"
            return
        if self._step is None:
            return
        if self._phase == "wait_hold":
            if p.state == "HOLD" and self._near_target(p):
                self._phase = "hold_pending"
            elif p.state == "FAULT":
                self._on_fault(p, prev)
        elif self._phase in ("hold_pending", "dwell") and p.state != "HOLD":
            self.summary.hold_restarts += 1
            self._j(
                "hold_lost",
                step=self._step.index,
                state=p.state,
                t_s=self._t_last,
                samples=self._dwell_rows if self._phase == "dwell" else 0,
            )
            self._phase = "wait_hold"
            self._cmd_idx, self._cmd_mono = None, self._clock()
            self._hold_retry = False
            if p.state == "FAULT":
                self._on_fault(p, prev)

    def _on_fault(self, p: Plt, prev: str) -> None:
        if prev != "FAULT":
            self.summary.faults += 1
            self._j("fault", step=self._step.index, t_s=self._t_last, angles=[p.x, p.y])
        idx = self._last_idx or 0
        every = self.opts.recommand_s * self.rate
        if self._last_recommand_idx is None or idx - self._last_recommand_idx >= every:
            self._last_recommand_idx = idx
            self.summary.recommands += 1
            self._send_tilt("fault")

    def _send_tilt(self, reason: str) -> None:
        st = self._step
        self._phase = "wait_hold"
        self._target = (st.x_arcsec, st.y_arcsec)
        self._commanding = True
        sent_rx = 0

        def send() -> int:
            nonlocal sent_rx
            sent_rx = self.platform.rx_count
            return self.platform.tilt(st.x_arcsec, st.y_arcsec, idle=self._idle)

        def obeyed() -> int | None:
            # a lost reply: if the platform already moves (or holds the target) after our
            # TILT, do not send it again (a platform may answer BUSY while it moves)
            if self._plt_rx > sent_rx and self._plt_state in ("MOVE", "HOLD"):
                if self._plt_state == "MOVE" or self._angles_near_target():
                    return sent_rx
            return None

        try:
            rx = self._call("platform", send, "TILT", accepted=obeyed)
        except DeviceError as e:
            cmd = f"{e.command} (step {st.index}: {st.label}, round {st.round})"
            raise DeviceError(e.port, cmd, e.reason) from None
        finally:
            self._commanding = False
        self._tilt_rx = rx
        self._cmd_idx, self._cmd_mono = None, self._clock()  # hold timeout counts from here
        self._j(
            "tilt", step=st.index, x=st.x_arcsec, y=st.y_arcsec, reason=reason, t_s=self._t_last
        )

    # ------------------------------------------------------------------ the run
    def _identify(self) -> None:
        idle = self._idle
        self.sensor_info = self._call("sensor", lambda: self.sensor.identify(idle=idle), "ID")
        self.rate = self._call("sensor", lambda: self.sensor.rate(idle=idle), "RATE")
        self.platform_info = self._call("platform", lambda: self.platform.identify(idle=idle), "ID")
        rs = self.resume_state
        if rs is not None:
            if self.sensor_info.serial != rs.serial:
                raise ChekanError(
                    f"{self.path}: record of sensor {rs.serial!r}, but the connected sensor is "
                    f"{self.sensor_info.serial!r}: not resuming"
                )
            if not math.isclose(self.rate, rs.rate_hz):
                raise ChekanError(
                    f"{self.path}: record at {rs.rate_hz:g} Hz, sensor now reports {self.rate:g} Hz"
                )

    def _start_record(self) -> None:
        if self.resume_state is None:
            meta = {
                "format": "chekan-record/1",
                "serial": self.sensor_info.serial,
                "instrument": "Chekan-AM",
                "model": self.sensor_info.model,
                "platform_serial": self.platform_info.serial,
                "started": self._utc(),
                "sample_rate_hz": f"{self.rate:g}",
                "program": self.program_name,
            }
            if self.plan:
                meta["program_dwell_s"] = f"{self.plan[0].dwell_s:g}"
                meta["program_settle_s"] = f"{self.plan[0].settle_s:g}"
            meta["sensor_firmware"] = self.sensor_info.firmware
            meta["platform_firmware"] = self.platform_info.firmware
            meta.update(self.meta)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = RecordWriter(self.path, meta, fsync_interval_s=self.opts.fsync_interval_s)
            self._j(
                "run_start",
                record=str(self.path),
                program=self.program_name,
                plan=[asdict(s) for s in self.plan],
                rate_hz=self.rate,
                sensor=asdict(self.sensor_info),
                platform=asdict(self.platform_info),
                options=self.opts.to_json(),
            )
        else:
            rs = self.resume_state
            self.writer = RecordWriter(
                self.path, None, append=True, fsync_interval_s=self.opts.fsync_interval_s
            )
            self.summary.steps_done = len(rs.done)
            self._j(
                "resume",
                from_step=rs.first_step,
                steps_done=sorted(rs.done),
                last_t_s=None if rs.last_idx is None else rs.last_idx / self.rate,
                torn_saved_to=self.writer.torn_path,
                options=self.opts.to_json(),
            )

    def _run_step(self, st: PlanStep) -> None:
        self._step = st
        self._dwell_n = max(1, round(st.dwell_s * self.rate))
        self._hold_retry = False
        self._last_recommand_idx = None
        self._j(
            "step_start",
            step=st.index,
            round=st.round,
            kind=st.kind,
            label=st.label,
            x=st.x_arcsec,
            y=st.y_arcsec,
            dwell_samples=self._dwell_n,
            t_s=self._t_last,
        )
        self._send_tilt("step")
        while self._phase != "done":
            self._pump()
        self.summary.steps_done += 1
        self._show(force=True)

    def _left_s(self) -> float:
        st = self._step
        if st is None:
            return sum(s.dwell_s for s in self.plan)
        rest = sum(s.dwell_s for s in self.plan[st.index + 1 :])
        if self._phase == "dwell":
            return rest + (self._dwell_n - (self._last_idx - self._dwell_start + 1)) / self.rate
        return rest + (0.0 if self._phase in ("done", "leveling", "level") else st.dwell_s)

    def _show(self, force: bool = False) -> None:
        if self.progress is None:
            return
        now = self._clock()
        if not force and now - self._last_progress < 0.2:
            return
        self._last_progress = now
        st = self._step
        phase = {"hold_pending": "hold", "wait_hold": "moving", "leveling": "level"}.get(
            self._phase, self._phase
        )
        self.progress(
            Progress(
                step=st.index if st else -1,
                n_steps=len(self.plan),
                round=st.round if st else 0,
                label=st.label if st else "",
                phase=phase,
                step_samples=self._dwell_rows if self._phase in ("dwell", "done") else 0,
                dwell_samples=self._dwell_n,
                t_s=self._t_last or 0.0,
                left_s=self._left_s(),
                samples=self.summary.samples,
                lost=self.summary.lost_samples,
                reconnects=sum(self.summary.reconnects.values()),
            )
        )

    def run(self) -> Summary:
        """Run (or continue) the program; never raises for device or link trouble."""
        s = self.summary
        status, code, message = "completed", EXIT_OK, ""
        try:
            self.journal = Journal(journal_path(self.path))
            self._open()
            self._identify()
            self._start_record()
            first = self.resume_state.first_step if self.resume_state else 0
            for st in self.plan[first:]:
                if self.resume_state and st.index in self.resume_state.done:
                    continue
                self._run_step(st)
        except KeyboardInterrupt:
            status, code, message = "interrupted", EXIT_INTERRUPTED, "interrupted (Ctrl-C)"
        except DeviceError as e:
            status, code, message = "device_error", EXIT_DEVICE, str(e)
        except (GaveUp, LinkLost, ReplyTimeout) as e:
            status, code, message = "gave_up", EXIT_GAVE_UP, str(e)
        except (ChekanError, FileExistsError) as e:
            status, code, message = "error", EXIT_CONFIG, str(e)
        except (HwError, OSError, ValueError) as e:
            status, code, message = "error", EXIT_DEVICE, f"{type(e).__name__}: {e}"
        finally:
            s.status, s.exit_code, s.message = status, code, message
            self._finish()
        return s

    def _level(self) -> None:
        """Level the platform and wait (recording) for its HOLD at 0, 0."""
        if self.platform is None:
            return
        self._closing = True
        self._step = None
        self._phase = "leveling"
        self._target = (0.0, 0.0)
        drv = self.platform
        try:
            if drv.down is not None or not drv.running:
                drv.stop()
                reopen(
                    drv.link,
                    give_up_at=self._clock() + min(self.opts.give_up_s, 10.0),
                    clock=self._clock,
                    sleep=self._sleep,
                )
                drv.start()
            rx = None
            for _ in range(3):
                try:
                    self._commanding = True
                    rx = drv.level(idle=self._idle)
                    break
                except ReplyTimeout:
                    continue
                finally:
                    self._commanding = False
            if rx is None:
                raise ReplyTimeout("platform", "LEVEL", self.opts.reply_timeout_s)
            self._tilt_rx = rx
            self._j("level", t_s=self._t_last)
            deadline = self._clock() + self.opts.level_wait_s
            while self._phase != "level" and self._clock() < deadline:
                self._pump(watch=False)
            self.summary.levelled = self._phase == "level"
            self._j("levelled" if self.summary.levelled else "level_unconfirmed", t_s=self._t_last)
        except (HwError, OSError) as e:
            self._j("level_failed", error=str(e))
            if not self.summary.message:
                self.summary.message = f"could not level the platform: {e}"
        except KeyboardInterrupt:
            self._j("level_interrupted")

    def _finish(self) -> None:
        s = self.summary
        try:
            if self.writer is not None or self.platform is not None:
                self._level()
        finally:
            for port, drv in self._drivers().items():
                if drv is not None:
                    drv.close()
                    s.dropped[port] = dict(drv.link.parser.stats)
            if self.writer is not None:
                try:
                    self._flush_rows()
                finally:
                    self.writer.close()
            self._j(
                "run_stop",
                status=s.status,
                exit_code=s.exit_code,
                message=s.message,
                summary=asdict(s),
            )
            if self.journal is not None:
                self.journal.close()
            if self.raw is not None:
                self.raw.close()
            if self.report is not None:
                self.report(s.format())


# ---------------------------------------------------------------------- entry points


def acquire(
    record_path: str | Path,
    program: TiltProgram,
    options: Options,
    *,
    g_local_mgal: float | str,
    meta: dict[str, str] | None = None,
    progress: Callable[[Progress], None] | None = None,
    report: Callable[[str], None] | None = print,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Summary:
    """Start a new run of ``program`` into a new record (refuses to overwrite one)."""
    path = Path(record_path)
    for p in (path, journal_path(path)):
        if p.exists():
            raise ChekanError(f"{p} exists: resume it (--resume) or choose another --out")
    user = dict(meta or {})
    bad = sorted(set(user) & set(PROTECTED_META))
    if bad:
        raise ChekanError(f"--meta cannot set {', '.join(bad)} (they come from the devices)")
    for k, v in user.items():
        if not re.fullmatch(r"[a-z0-9_]+", str(k)) or "\n" in str(v) or "\r" in str(v):
            raise ChekanError(f"--meta {k}={v!r}: key of [a-z0-9_], value on one line")
    try:
        g = float(g_local_mgal)
    except (TypeError, ValueError):
        g = math.nan
    if not math.isfinite(g):
        raise ChekanError(f"g_local_mgal must be a finite number, not {g_local_mgal!r}")
    user["g_local_mgal"] = str(g_local_mgal).strip() if isinstance(g_local_mgal, str) else repr(g)
    acq = Acquisition(
        path,
        plan_from_program(program),
        options,
        program_name=program.name,
        meta=user,
        progress=progress,
        report=report,
        clock=clock,
        sleep=sleep,
    )
    return acq.run()


def _step_complete_in_record(rec, step: int, n: int, rate: float) -> bool:
    """Whether the last contiguous run of ``step`` rows covers ``n`` sample periods."""
    where = np.flatnonzero(rec.step == step)
    if where.size == 0:
        return False
    breaks = np.flatnonzero(np.diff(where) != 1)
    start = where[breaks[-1] + 1] if breaks.size else where[0]
    stop = where[-1]
    span = round((rec.t_s[stop] - rec.t_s[start]) * rate) + 1
    return span >= n


def resume_state(record_path: str | Path) -> tuple[ResumeState | None, dict, list[PlanStep], dict]:
    """Read journal + record: ``(state or None if complete, run_start event, plan, last sync)``."""
    path = Path(record_path)
    jp = journal_path(path)
    if not jp.exists():
        raise ChekanError(f"{jp}: no journal: nothing to resume (start a new run instead)")
    events = read_journal(jp)
    start = next((e for e in events if e["event"] == "run_start"), None)
    if start is None:
        raise ChekanError(f"{jp}: the run never started recording: start a new run instead")
    plan = [PlanStep.from_json(d) for d in start["plan"]]
    rate = float(start["rate_hz"])
    done = {int(e["step"]) for e in events if e["event"] == "step_done"}
    stops = [e for e in events if e["event"] == "run_stop"]
    if stops and stops[-1].get("status") == "completed" and len(done) >= len(plan):
        return None, start, plan, {}  # complete and levelled: nothing to do
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = read_record(path)
    first = next((st for st in plan if st.index not in done), None)
    if first is not None and _step_complete_in_record(  # rows complete, step_done not journaled
        rec, first.index, max(1, round(first.dwell_s * rate)), rate
    ):
        done.add(first.index)
    pending = [st.index for st in plan if st.index not in done]
    syncs = [e for e in events if e["event"] == "sync"]
    last_idx = last_seq = None
    if rec.n and syncs:
        ref = syncs[-1]
        last_idx = round(float(rec.t_s[-1]) * rate)
        ref_idx = round(float(ref["t_ref"]) * rate)
        last_seq = (int(ref["seq_ref"]) + last_idx - ref_idx) % SEQ_MOD
    elif rec.n:
        last_idx = round(float(rec.t_s[-1]) * rate)
    state = ResumeState(  # all steps done but never stopped cleanly: it only levels
        first_step=pending[0] if pending else len(plan),
        done=done,
        last_idx=last_idx,
        last_seq=last_seq,
        rate_hz=rate,
        serial=str(start["sensor"]["serial"]),
    )
    return state, start, plan, syncs[-1] if syncs else {}


def resume(
    record_path: str | Path,
    *,
    sensor_url: str | None = None,
    platform_url: str | None = None,
    options: Options | None = None,
    overrides: dict | None = None,
    progress: Callable[[Progress], None] | None = None,
    report: Callable[[str], None] | None = print,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Summary:
    """Continue a killed or interrupted run of ``record_path`` (see the module docstring).

    Ports and options come from the journal unless given (``overrides``: Options fields).
    """
    state, start, plan, _ = resume_state(record_path)
    if state is None:
        s = Summary(status="completed", n_steps=len(plan), steps_done=len(plan))
        s.message = "nothing to resume: the run is complete"
        if report is not None:
            report(s.message)
        return s
    opts = options or Options.from_json(start.get("options", {}))
    for k, v in (overrides or {}).items():
        if v is not None:
            setattr(opts, k, v)
    if sensor_url:
        opts.sensor_url = sensor_url
    if platform_url:
        opts.platform_url = platform_url
    if not opts.sensor_url or not opts.platform_url:
        raise ChekanError("resume: the ports are not in the journal: give --sensor and --platform")
    acq = Acquisition(
        record_path,
        plan,
        opts,
        program_name=str(start.get("program", "custom")),
        resume_state=state,
        progress=progress,
        report=report,
        clock=clock,
        sleep=sleep,
    )
    return acq.run()
