"""The runner: one session (new or resumed) of a plan, from opening the ports to levelling.

It wires the parts together: :class:`~hw.acquisition.links.LinkSupervisor` (ports),
:class:`~hw.acquisition.clock.SampleClock` (``seq`` → ``t_s``),
:class:`~hw.acquisition.steps.StepMachine` (TILT, HOLD, dwell) and
:class:`~hw.acquisition.recorder.Recorder` (record, journal, raw log); it pumps the
drivers' events into them and turns every outcome into a :class:`Summary`.
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from chekan.errors import ChekanError
from hw.acquisition.clock import SampleClock
from hw.acquisition.links import LinkSupervisor
from hw.acquisition.plan import (
    EXIT_CONFIG,
    EXIT_DEVICE,
    EXIT_GAVE_UP,
    EXIT_INTERRUPTED,
    EXIT_OK,
    Options,
    PlanStep,
)
from hw.acquisition.recorder import Recorder, record_meta
from hw.acquisition.steps import StepMachine
from hw.acquisition.summary import Summary
from hw.drivers import LinkDown, PlatformInfo, Received, SensorInfo
from hw.errors import (
    DeviceError,
    DwellCut,
    GaveUp,
    HwError,
    LinkLost,
    ReplyTimeout,
    StorageFailed,
)
from hw.events import Event
from hw.nmea import Grv, Plt
from hw.progress import Progress

if TYPE_CHECKING:
    from hw.acquisition.resume import ResumeState

MAX_EVENTS_PER_PUMP = 200
PROGRESS_INTERVAL_S = 0.2


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
        report: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        utc: Callable[[], str] | None = None,
    ):
        self.path = Path(record_path)
        self.plan = plan
        self.opts = options
        self.program_name = program_name
        self.meta = dict(meta or {})
        self.resume_state = resume_state
        self.progress = progress
        self.report = report
        self._utc = utc or _utc_stamp
        self._clock = clock
        self.summary = Summary(n_steps=len(plan))
        self.rate = 1.0
        self.sensor_info: SensorInfo | None = None
        self.platform_info: PlatformInfo | None = None
        self.recorder = Recorder(self.path, fsync_interval_s=options.fsync_interval_s, clock=clock)
        self.samples: SampleClock | None = None  # once the sensor reported its rate
        self.links = LinkSupervisor(
            options, self.recorder.event, self._t_last, clock=clock, sleep=sleep
        )
        self.steps = StepMachine(options, self.recorder.event, self._tilt, clock=clock)
        self._last_progress = 0.0
        self._ending = False  # levelling at the end: a failed write no longer stops the pump
        self._samples_broken = False  # a sample failed while levelling: record no more

    def _t_last(self) -> float | None:
        return None if self.samples is None else self.samples.t_last

    # ------------------------------------------------------------------ events
    def _pump(self, timeout: float = 0.05, watch: bool = True) -> None:
        """Handle queued events (waiting up to ``timeout`` for the first), then watch links."""
        events = self.links.events
        try:
            ev: Received | LinkDown | None = events.get(timeout=timeout)
        except queue.Empty:
            ev = None
        n = 0
        while ev is not None:
            try:
                self._handle(ev)
            except Exception:
                if not self._ending:
                    raise
                self._samples_broken = True  # levelling goes on; no more rows
            n += 1
            if n >= MAX_EVENTS_PER_PUMP:
                break
            try:
                ev = events.get_nowait()
            except queue.Empty:
                ev = None
        self.recorder.flush()
        failure = self.recorder.check()
        if failure is not None and not self._ending:
            raise failure
        if watch and not self.steps.commanding:
            self.links.watch()

    def _idle(self) -> None:
        """While a query waits: keep recording (no commands, no reconnects)."""
        self._pump(timeout=0.0, watch=False)

    def _handle(self, ev: Received | LinkDown) -> None:
        if isinstance(ev, LinkDown):
            return  # the driver's ``down`` is seen by the link supervisor's watch
        s = ev.sentence
        if isinstance(s, Grv):
            self._on_sample(s, ev.t_mono)
        elif isinstance(s, Plt):
            self.steps.on_status(ev.rx, s)

    def _on_sample(self, g: Grv, t_mono: float) -> None:
        clock, steps = self.samples, self.steps
        if clock is None or not self.recorder.recording or self._samples_broken:
            return
        if not clock.started and steps.status.angles is None:
            return  # the record starts with the first sample after a platform status
        idx = clock.index(g.seq, steps.step.index if steps.step else None)
        if idx is None:
            return
        step = steps.on_sample(idx, first_row=self.recorder.stats.samples == 0)
        self.recorder.add_sample(idx / clock.rate, g, steps.angles_for_sample(), step)
        steps.after_sample(idx, t_mono)
        self._show()

    def _tilt(self, st: PlanStep) -> int:
        """Send ``st``'s TILT (retried through the link supervisor); its reply's rx number."""
        platform = self.links.platform
        assert platform is not None
        sent_rx = 0

        def send() -> int:
            nonlocal sent_rx
            sent_rx = platform.rx_count
            return platform.tilt(st.x_arcsec, st.y_arcsec, idle=self._idle)

        try:
            return self.links.call(
                "platform", send, "TILT", accepted=lambda: self.steps.obeyed(sent_rx)
            )
        except DeviceError as e:
            cmd = f"{e.command} (step {st.index}: {st.label}, round {st.round})"
            raise DeviceError(e.port, cmd, e.reason) from None

    # ------------------------------------------------------------------ the run
    def _identify(self) -> None:
        idle, links = self._idle, self.links
        sensor, platform = links.sensor, links.platform
        assert sensor is not None and platform is not None
        self.sensor_info = links.call("sensor", lambda: sensor.identify(idle=idle), "ID")
        self.rate = links.call("sensor", lambda: sensor.rate(idle=idle), "RATE")
        self.platform_info = links.call("platform", lambda: platform.identify(idle=idle), "ID")
        rs = self.resume_state
        if rs is not None:
            rs.check_instrument(self.path, self.sensor_info.serial, self.rate)
        self.samples = SampleClock(
            self.rate, self.recorder.event, None if rs is None else rs.anchor
        )
        self.steps.attach(self.samples)

    def _start_record(self) -> None:
        rs, rec = self.resume_state, self.recorder
        assert self.sensor_info is not None and self.platform_info is not None
        if rs is None:
            first = self.plan[0] if self.plan else None
            rec.create(
                record_meta(
                    self.sensor_info,
                    self.platform_info,
                    rate_hz=self.rate,
                    program=self.program_name,
                    dwell_s=first.dwell_s if first else None,
                    settle_s=first.settle_s if first else None,
                    steps=len(self.plan),
                    started=self._utc(),
                    user=self.meta,
                )
            )
            rec.event(
                Event.RUN_START,
                record=str(self.path),
                program=self.program_name,
                plan=[asdict(s) for s in self.plan],
                rate_hz=self.rate,
                sensor=asdict(self.sensor_info),
                platform=asdict(self.platform_info),
                options=self.opts.to_json(),
            )
        else:
            torn = rec.append()
            self.summary.steps_done = len(rs.done)
            rec.event(
                Event.RESUME,
                from_step=rs.first_step,
                steps_done=sorted(rs.done),
                last_t_s=None if rs.last_idx is None else rs.last_idx / self.rate,
                torn_saved_to=torn,
                options=self.opts.to_json(),
            )

    def _await_platform(self) -> None:
        """Wait (recording) for the platform's first status, up to ``timeout_s``: where it
        stands decides whether the first step goes through level (a resumed run may find
        it tilted about the other axis)."""
        deadline = self._clock() + self.opts.timeout_s
        while self.steps.status.angles is None and self._clock() < deadline:
            self._pump()

    def _run_step(self, st: PlanStep) -> None:
        self.steps.begin(st)
        while not self.steps.step_done:
            self._pump()
        self.summary.steps_done += 1
        self._show(force=True)

    def run(self) -> Summary:
        """Run (or continue) the program; never raises for device, link or disk trouble
        (a file that cannot be written stops the run: levelled, record closed, exit 1)."""
        status, code, message = "completed", EXIT_OK, ""
        try:
            self.recorder.open_journal()
            self.links.open(self.recorder.open_raw_log())
            self._identify()
            self._start_record()
            self._await_platform()
            rs = self.resume_state
            for st in self.plan[rs.first_step if rs else 0 :]:
                if rs and st.index in rs.done:
                    continue
                self._run_step(st)
        except KeyboardInterrupt:
            status, code, message = "interrupted", EXIT_INTERRUPTED, "interrupted (Ctrl-C)"
        except StorageFailed as e:
            status, code, message = "stopped", EXIT_DEVICE, str(e)
        except DeviceError as e:
            status, code, message = "device_error", EXIT_DEVICE, str(e)
        except (GaveUp, LinkLost, ReplyTimeout, DwellCut) as e:
            status, code, message = "gave_up", EXIT_GAVE_UP, str(e)
        except (ChekanError, FileExistsError) as e:
            status, code, message = "error", EXIT_CONFIG, str(e)
        except (HwError, OSError, ValueError) as e:
            status, code, message = "error", EXIT_DEVICE, f"{type(e).__name__}: {e}"
        except Exception as e:  # any other fatal error: level and close first, then say it
            status, code, message = "error", EXIT_DEVICE, f"unexpected {type(e).__name__}: {e}"
        finally:
            s = self.summary
            s.status, s.exit_code, s.message = status, code, message
            self._finish()
        return self.summary

    # ------------------------------------------------------------------ the end
    def _level(self) -> None:
        """Level the platform and wait (recording) for its HOLD at 0, 0."""
        if self.links.platform is None:
            return
        self.links.watching = False
        self.steps.start_leveling()
        rec, opts = self.recorder, self.opts
        try:
            drv = self.links.revive_platform(within_s=min(opts.give_up_s, 10.0))
            rx = None
            for _ in range(3):
                try:
                    with self.steps.command():
                        rx = drv.level(idle=self._idle)
                    break
                except ReplyTimeout:
                    continue
            if rx is None:
                raise ReplyTimeout("platform", "LEVEL", opts.reply_timeout_s)
            self.steps.level_sent(rx)
            rec.event(Event.LEVEL, t_s=self._t_last())
            deadline = self._clock() + opts.level_wait_s
            while not self.steps.levelled and self._clock() < deadline:
                self._pump(watch=False)
            self.summary.levelled = self.steps.levelled
            rec.event(
                Event.LEVELLED if self.summary.levelled else Event.LEVEL_UNCONFIRMED,
                t_s=self._t_last(),
            )
        except (HwError, OSError) as e:
            rec.event(Event.LEVEL_FAILED, error=str(e))
            if not self.summary.message:
                self.summary.message = f"could not level the platform: {e}"
        except KeyboardInterrupt:
            rec.event(Event.LEVEL_INTERRUPTED)

    def _collect(self) -> None:
        """Copy the parts' counts into the summary."""
        s = self.summary
        if self.samples is not None:
            c = self.samples.stats
            s.gaps, s.lost_samples = c.gaps, c.lost_samples
            s.duplicates, s.out_of_order = c.duplicates, c.out_of_order
        r = self.recorder.stats
        s.samples, s.t_s_first, s.t_s_last = r.samples, r.t_s_first, r.t_s_last
        s.saturated, s.therm = r.saturated, r.therm
        p = self.steps.stats
        s.faults, s.recommands, s.hold_restarts = p.faults, p.recommands, p.hold_restarts
        s.reconnects = dict(self.links.reconnects)

    def _finish(self) -> None:
        s, rec = self.summary, self.recorder
        self._ending = True
        try:
            if rec.recording or self.links.platform is not None:
                self._level()
        finally:
            s.dropped.update(self.links.close())
            rec.close_record()
            rec.close_raw_log()
            failure = rec.check()
            if failure is not None and s.exit_code == EXIT_OK:  # the raw log's last lines
                s.status, s.exit_code, s.message = "error", EXIT_DEVICE, str(failure)
            self._collect()
            rec.event(
                Event.RUN_STOP,
                status=s.status,
                exit_code=s.exit_code,
                message=s.message,
                summary=asdict(s),
            )
            rec.close()
            if self.resume_state is None and rec.remove_if_unborn():
                s.message += (
                    "; nothing was recorded: the empty record and its journal were removed, "
                    "so the same record can be started again"
                )
            if self.report is not None:
                self.report(s.format())

    # ------------------------------------------------------------------ progress
    def _show(self, force: bool = False) -> None:
        if self.progress is None:
            return
        now = self._clock()
        if not force and now - self._last_progress < PROGRESS_INTERVAL_S:
            return
        self._last_progress = now
        steps, st = self.steps, self.steps.step
        lost = self.samples.stats.lost_samples if self.samples is not None else 0
        self.progress(
            Progress(
                step=st.index if st else -1,
                n_steps=len(self.plan),
                round=st.round if st else 0,
                label=st.label if st else "",
                axis=st.axis if st else "",
                phase=steps.phase.shown,
                step_samples=steps.step_samples,
                dwell_samples=steps.dwell_n,
                t_s=self._t_last() or 0.0,
                left_s=steps.left_s(self.plan),
                samples=self.recorder.stats.samples,
                lost=lost,
                reconnects=sum(self.links.reconnects.values()),
            )
        )
