"""The step machine: TILT, wait for the HOLD at the target, count the dwell in samples.

For each step the machine sends ``TILT`` (through the runner's ``send_tilt``),
waits for a ``HOLD`` within ``angle_tol_arcsec`` reported after the command's
reply, then counts ``round(dwell_s × rate)`` sample periods on the sample clock
from the first sample after the hold. A platform ``FAULT`` re-sends the ``TILT``
(every ``recommand_s`` while it lasts) and restarts the dwell at the next
``HOLD``; no HOLD within ``hold_timeout_s`` re-sends it once, then is an error.
At the end the platform is levelled (:attr:`Phase.LEVELING` → :attr:`Phase.LEVEL`).

A dwell is one uninterrupted run of rows: lost samples (a ``seq`` jump: dropped or
garbled lines, a stalled or vanished sensor port) or platform statuses gone stale
(its port silent: the hold is unverified) cut it, and it is dwelt again in full, its
settling included (the settle is the start of the dwell). The first row after a cut
carries no step, so the cut run and the new one are separate holds in the record (as
the first row of a resumed session); a step cut ``max_dwell_cuts`` times gives up.

The platform changes axis only through level: a step about one axis that would start
while the platform stands tilted about the other (beyond ``angle_tol_arcsec``: a
program whose rounds alternate axes without a level step between them, or a resumed
run) first commands ``TILT 0,0`` and waits for its HOLD (journaled as a ``tilt`` with
reason ``via level``; those rows belong to no step), then the step's own target.
"""

from __future__ import annotations

import contextlib
import enum
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace

from hw.acquisition.clock import SampleClock
from hw.acquisition.plan import Options, PlanStep
from hw.acquisition.recorder import EventLog
from hw.errors import DeviceError, DwellCut
from hw.events import Event
from hw.nmea import Plt


class Phase(enum.Enum):
    """Where the machine is; :attr:`shown` is the name in the progress line."""

    IDLE = "idle"
    WAIT_HOLD = "wait_hold"  # TILT sent, the platform moves
    HOLD_PENDING = "hold_pending"  # HOLD at the target; the dwell starts at the next sample
    DWELL = "dwell"
    DONE = "done"
    LEVELING = "leveling"  # LEVEL sent at the end
    LEVEL = "level"  # HOLD at 0, 0

    @property
    def shown(self) -> str:
        """The phase as the progress line names it."""
        return _SHOWN.get(self, self.value)


_SHOWN = {Phase.HOLD_PENDING: "hold", Phase.WAIT_HOLD: "moving", Phase.LEVELING: "level"}


@dataclass
class PlatformStatus:
    """The latest ``PLT`` of the platform."""

    angles: tuple[float, float] | None = None
    state: str = ""
    rx: int = 0  # its receive number on the platform port
    mono: float = -1e18  # host time it came
    samples_since: int = 10**9  # sensor samples since it came


@dataclass
class StepStats:
    """What the platform did in this session."""

    faults: int = 0  # FAULT episodes
    recommands: int = 0  # TILT re-sent (FAULT, hold timeout)
    hold_restarts: int = 0  # dwells restarted (hold lost, samples lost, platform silent)


class StepMachine:
    """Runs one :class:`PlanStep` at a time (owns its phase, the platform status and stats)."""

    def __init__(
        self,
        opts: Options,
        journal: EventLog,
        send_tilt: Callable[[PlanStep], int],
        *,
        clock: Callable[[], float],
    ):
        self.opts = opts
        self._journal = journal
        self._send = send_tilt
        self._clock = clock
        self.samples: SampleClock | None = None  # attached once the sensor's rate is known
        self.status = PlatformStatus()
        self.stats = StepStats()
        self.phase = Phase.IDLE
        self.step: PlanStep | None = None
        self.commanding = False  # a command's reply is awaited: statuses are not acted on
        self._target = (0.0, 0.0)
        self._tilt_rx = 0  # receive number of the last command's reply
        self._cmd_idx: int | None = None  # first sample after the last command's reply
        self._cmd_mono = 0.0
        self._hold_retry = False
        self._last_recommand_idx: int | None = None
        self._via_level = False  # the current TILT is the level leg before the step's own
        self.dwell_start = 0
        self.dwell_n = 0
        self.dwell_rows = 0
        self.dwell_cuts = 0  # this step's dwells cut short so far
        self._prev_idx: int | None = None  # index of the last sample seen
        self._stale = False  # the last sample came with stale platform angles
        self.gave_up: DwellCut | None = None  # too many cuts: the run stops at the next row

    # ------------------------------------------------------------------ helpers
    def attach(self, samples: SampleClock) -> None:
        """Count on ``samples`` (the session's sample clock)."""
        self.samples = samples

    @property
    def _rate(self) -> float:
        return 1.0 if self.samples is None else self.samples.rate

    def _t_last(self) -> float | None:
        return None if self.samples is None else self.samples.t_last

    @contextlib.contextmanager
    def command(self) -> Iterator[None]:
        """While a command waits for its reply, statuses and samples do not move the machine."""
        self.commanding = True
        try:
            yield
        finally:
            self.commanding = False

    def _crosses_axes(self, st: PlanStep) -> bool:
        """Whether ``st``'s target lies about the other axis than the platform now stands:
        going straight there would tilt about both axes at once."""
        here = self.status.angles if self.status.angles is not None else self._target
        tol = self.opts.angle_tol_arcsec
        return (abs(here[0]) > tol and st.y_arcsec != 0.0) or (
            abs(here[1]) > tol and st.x_arcsec != 0.0
        )

    def _near_target(self, x: float, y: float) -> bool:
        tol = self.opts.angle_tol_arcsec
        return abs(x - self._target[0]) <= tol and abs(y - self._target[1]) <= tol

    def obeyed(self, sent_rx: int) -> int | None:
        """After a lost TILT reply: ``sent_rx`` if the platform evidently obeyed, else None.

        It obeyed if it moves (or holds the target) in a status after the command was
        sent (a platform may answer BUSY while it moves, so it is not sent again).
        """
        st = self.status
        if st.rx > sent_rx and st.state in ("MOVE", "HOLD"):
            if st.state == "MOVE" or (st.angles is not None and self._near_target(*st.angles)):
                return sent_rx
        return None

    # ------------------------------------------------------------------ steps
    def begin(self, st: PlanStep) -> None:
        """Start ``st``: journal it and send its TILT."""
        self.step = st
        self.dwell_n = st.dwell_samples(self._rate)
        self.dwell_cuts = 0
        self._hold_retry = False
        self._last_recommand_idx = None
        self._journal(
            Event.STEP_START,
            step=st.index,
            round=st.round,
            kind=st.kind,
            label=st.label,
            axis=st.axis,
            x=st.x_arcsec,
            y=st.y_arcsec,
            dwell_samples=self.dwell_n,
            t_s=self._t_last(),
        )
        self._via_level = self._crosses_axes(st)
        self._send_tilt("via level" if self._via_level else "step")

    @property
    def step_done(self) -> bool:
        """Whether the current step's dwell is complete."""
        return self.phase is Phase.DONE

    def _send_tilt(self, reason: str) -> None:
        """TILT to the step's target, or to level first while :attr:`_via_level`."""
        st = self.step
        assert st is not None
        leg = replace(st, label="level", x_arcsec=0.0, y_arcsec=0.0) if self._via_level else st
        self.phase = Phase.WAIT_HOLD
        self._target = (leg.x_arcsec, leg.y_arcsec)
        with self.command():
            rx = self._send(leg)
        self._tilt_rx = rx
        self._cmd_idx, self._cmd_mono = None, self._clock()  # hold timeout counts from here
        self._journal(
            Event.TILT,
            step=st.index,
            x=leg.x_arcsec,
            y=leg.y_arcsec,
            reason=reason,
            t_s=self._t_last(),
        )

    def start_leveling(self) -> None:
        """No step any more: wait for a HOLD at 0, 0 after the LEVEL command's reply."""
        self.step = None
        self.phase = Phase.LEVELING
        self._target = (0.0, 0.0)

    def level_sent(self, rx: int) -> None:
        """The LEVEL command was answered with receive number ``rx``."""
        self._tilt_rx = rx

    @property
    def levelled(self) -> bool:
        """Whether the platform holds level after :meth:`start_leveling`."""
        return self.phase is Phase.LEVEL

    # ------------------------------------------------------------------ platform
    def on_status(self, rx: int, p: Plt) -> None:
        """A platform status: HOLD at the target, hold lost, FAULT."""
        prev = self.status.state
        self.status = PlatformStatus((p.x, p.y), p.state, rx, self._clock(), 0)
        if self.commanding or rx <= self._tilt_rx:
            return  # sent before the platform saw our last command
        if self.phase is Phase.LEVELING:
            if p.state == "HOLD" and self._near_target(p.x, p.y):
                self.phase = Phase.LEVEL
            return
        st = self.step
        if st is None:
            return
        if self.phase is Phase.WAIT_HOLD:
            if p.state == "HOLD" and self._near_target(p.x, p.y) and self._via_level:
                self._via_level = False  # level reached: now the step's own target
                self._hold_retry = False
                self._send_tilt("step")
            elif p.state == "HOLD" and self._near_target(p.x, p.y):
                self.phase = Phase.HOLD_PENDING
            elif p.state == "FAULT":
                self._on_fault(p, prev)
        elif self.phase in (Phase.HOLD_PENDING, Phase.DWELL) and p.state != "HOLD":
            self._cut(p.state, self._t_last())
            self._wait_hold_again()
            if p.state == "FAULT":
                self._on_fault(p, prev)

    def _wait_hold_again(self) -> None:
        """The hold is lost: wait for a new HOLD (the hold timeout counts from now)."""
        self.phase = Phase.WAIT_HOLD
        self._cmd_idx, self._cmd_mono = None, self._clock()
        self._hold_retry = False

    def _cut(self, why: str, t_s: float | None, **extra: object) -> None:
        """Journal the end of the current hold or dwell before its full length (``why``:
        the platform state, ``GAP`` for lost samples, ``SILENT`` for stale statuses); give
        up when the step's dwell has been cut ``max_dwell_cuts`` times."""
        st = self.step
        assert st is not None
        self.stats.hold_restarts += 1
        self._journal(
            Event.HOLD_LOST,
            step=st.index,
            state=why,
            t_s=t_s,
            samples=self.dwell_rows if self.phase is Phase.DWELL else 0,
            **extra,
        )
        if self.phase is Phase.DWELL:
            self.dwell_cuts += 1
            if self.dwell_cuts >= self.opts.max_dwell_cuts:  # raised once the row is written
                self.gave_up = DwellCut(
                    st.index, st.label, self.dwell_n / self._rate, self.dwell_cuts
                )

    def _on_fault(self, p: Plt, prev: str) -> None:
        st = self.step
        assert st is not None
        if prev != "FAULT":
            self.stats.faults += 1
            self._journal(Event.FAULT, step=st.index, t_s=self._t_last(), angles=[p.x, p.y])
        idx = (self.samples.last_idx if self.samples is not None else None) or 0
        every = self.opts.recommand_s * self._rate
        if self._last_recommand_idx is None or idx - self._last_recommand_idx >= every:
            self._last_recommand_idx = idx
            self.stats.recommands += 1
            self._send_tilt("fault")

    # ------------------------------------------------------------------ samples
    def angles_for_sample(self) -> tuple[float, float] | None:
        """The platform angles to write with the sample just placed by :meth:`on_sample`
        (None when stale)."""
        return None if self._stale else self.status.angles

    def on_sample(self, idx: int, first_row: bool) -> int | None:
        """A sample at ``idx`` is about to be written: the step it belongs to (None: none).

        The first row of a session never belongs to a dwell (on resume it separates runs),
        nor does the first after samples were lost or while the platform's statuses are
        stale: those cut a dwell, which starts again in full.
        """
        s = self.status
        s.samples_since += 1
        self._stale = (
            s.samples_since > self.opts.stale_s * self._rate
            and self._clock() - s.mono > self.opts.stale_s
        )  # old on the sample clock AND in host time (an accelerated emulator's ports skew)
        prev, self._prev_idx = self._prev_idx, idx
        st = self.step
        if st is None or self.commanding:
            pass
        elif self._stale and self.phase in (Phase.HOLD_PENDING, Phase.DWELL):
            self._cut("SILENT", idx / self._rate)  # the hold is unverified: wait for a HOLD
            self._wait_hold_again()
            return None
        elif self.phase is Phase.DWELL and prev is not None and idx - prev > 1:
            self._cut("GAP", idx / self._rate, lost=idx - prev - 1)
            self.phase = Phase.HOLD_PENDING  # still holding: the dwell restarts after this row
            return None
        if self.phase is Phase.HOLD_PENDING and not self.commanding and not first_row:
            assert st is not None
            self.phase = Phase.DWELL
            self.dwell_start = idx
            self.dwell_rows = 0
            self._journal(
                Event.HOLD, step=st.index, t_s=idx / self._rate, angles=self.status.angles
            )
        if self.phase is Phase.DWELL and idx < self.dwell_start + self.dwell_n:
            assert st is not None
            self.dwell_rows += 1
            return st.index
        return None

    def after_sample(self, idx: int, t_mono: float) -> None:
        """The sample at ``idx`` (received at ``t_mono``) is written: dwell end, hold timeout."""
        if self.gave_up is not None:  # raised once: the rows while levelling are recorded
            err, self.gave_up = self.gave_up, None
            raise err
        if self._cmd_idx is None and t_mono >= self._cmd_mono:
            self._cmd_idx = idx  # the first sample received after the command's reply
        if self.commanding:
            return
        st = self.step
        if self.phase is Phase.DWELL and idx >= self.dwell_start + self.dwell_n - 1:
            assert st is not None
            self.phase = Phase.DONE
            self._journal(
                Event.STEP_DONE,
                step=st.index,
                t_s_first=self.dwell_start / self._rate,
                t_s_last=min(idx, self.dwell_start + self.dwell_n - 1) / self._rate,
                samples=self.dwell_rows,
                lost=self.dwell_n - self.dwell_rows,
            )
        elif self.phase is Phase.WAIT_HOLD and st is not None and self._cmd_idx is not None:
            waited = idx - self._cmd_idx
            if waited > self.opts.hold_timeout_s * self._rate:
                if self._hold_retry:
                    raise DeviceError(
                        "platform",
                        f"TILT {self._target[0]:g} {self._target[1]:g}",
                        f"no HOLD at the target within {self.opts.hold_timeout_s:g} s of "
                        f"sample clock (state {self.status.state or '?'}, "
                        f"angles {self.status.angles})",
                    )
                self._hold_retry = True
                self.stats.recommands += 1
                self._journal(Event.HOLD_TIMEOUT, step=st.index, t_s=idx / self._rate)
                self._send_tilt("hold timeout")

    # ------------------------------------------------------------------ progress
    def left_s(self, plan: Sequence[PlanStep]) -> float:
        """Sample-clock seconds of dwell left in ``plan``."""
        st = self.step
        if st is None:
            return sum(s.dwell_s for s in plan)
        rest = sum(s.dwell_s for s in plan[st.index + 1 :])
        last = self.samples.last_idx if self.samples is not None else None
        if self.phase is Phase.DWELL and last is not None:
            return rest + (self.dwell_n - (last - self.dwell_start + 1)) / self._rate
        done = self.phase in (Phase.DONE, Phase.LEVELING, Phase.LEVEL)
        return rest + (0.0 if done else st.dwell_s)

    @property
    def step_samples(self) -> int:
        """Samples of the current dwell recorded so far."""
        return self.dwell_rows if self.phase in (Phase.DWELL, Phase.DONE) else 0
