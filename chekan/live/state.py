"""What the live page shows, built from the files an acquisition writes.

:class:`LiveState` follows the record, its journal and its raw log
(:mod:`chekan.live.follow`), keeps the rows so far, and derives from them the current
step and its dwell, the time left, link health, alarms and the running calibration
(:mod:`chekan.live.calib`). :meth:`LiveState.update` is cheap when nothing changed and is
called from one thread; readers take :meth:`status` and :meth:`rows_since`.
"""

from __future__ import annotations

import math
import os
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from chekan.live import calib
from chekan.live.follow import (
    COLUMNS,
    JournalFollower,
    RawLogFollower,
    RecordFollower,
    journal_locked,
)
from hw.acquisition.steps import Phase
from hw.events import Event

STALL_S = 20.0  # wall seconds without a new row (run not stopped) before the stall alarm
CCD_MARGIN = 0.05  # fraction of the CCD range near either end that raises the alarm
MOVE_ALARM_S = 180.0  # sample-clock seconds a step may wait for HOLD before the alarm
GONE_S = 5.0  # wall seconds of a quiet record, its journal unlocked, before "acquisition gone"
GONE = "acquisition gone (no end journalled)"

_PLOT = ("t_s", "m1_pix", "m2_pix", "tilt_x_arcsec", "tilt_y_arcsec")
_READINGS = ("m1_pix", "m2_pix", "tilt_x_arcsec", "tilt_y_arcsec", "temp_c")
PACE_MIN_S = 30.0  # sample-clock seconds of journal before its pace replaces 1 s per s


def _utc(text: object) -> datetime | None:
    """A journal ``utc`` stamp (ISO 8601, ``Z``) as an aware datetime; None if unreadable."""
    try:
        return datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        return None


def _iso(d: datetime) -> str:
    return d.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def step_axis(x_arcsec: float, y_arcsec: float) -> str:
    """The axis a target tilts about ("x" when |x| > |y|, as :mod:`chekan.records.holds`
    classifies)."""
    return "x" if abs(x_arcsec) > abs(y_arcsec) else "y"


_DEC = {"t_s": 3, "m1_pix": 4, "m2_pix": 4, "tilt_x_arcsec": 2, "tilt_y_arcsec": 2}


def _jsonable(a: np.ndarray, decimals: int) -> list:
    r = np.round(a, decimals)
    return [None if v != v else v for v in r.tolist()]  # NaN → null


class LiveState:
    def __init__(
        self,
        record_path: str | Path,
        *,
        map_runner: calib.MapRunner | None = None,
        clock=time.monotonic,
        stall_s: float = STALL_S,
        program=None,
    ):
        self.path = Path(record_path)
        self.record = RecordFollower(self.path)
        self.journal = JournalFollower(f"{self.path}.journal.jsonl")
        self.raw = RawLogFollower(f"{self.path}.raw.log")
        self.map = map_runner if map_runner is not None else calib.MapRunner()
        self._clock = clock
        self.stall_s = stall_s
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        self.version = 0
        self.program = program
        self._reset()

    def quiet_s(self) -> float:
        """Wall seconds since the record last grew."""
        return self._clock() - self.last_growth

    def _reset(self) -> None:
        self._chunks: list[dict[str, np.ndarray]] = []
        self._cols: dict[str, np.ndarray] = {c: np.zeros(0) for c in COLUMNS}
        self.n = 0
        self.events: list[dict] = []
        self.plan: list[dict] = []
        self.rate = 1.0
        self.run_start: dict | None = None
        self.run_stop: dict | None = None
        self.current: dict | None = None  # last step_start
        self.hold: dict | None = None  # hold event of the current step
        self.done_steps: set[int] = set()
        self.runs: list[list] = []  # [t0, t1, step] of the step column's runs
        self.gaps = 0
        self.lost = 0
        self.health: dict[str, Any] = {
            "reconnects": {},
            "link_lost": {},
            "faults": 0,
            "hold_lost": 0,
            "hold_timeouts": 0,
            "reply_timeouts": 0,
            "sat_episodes": 0,
            "therm_episodes": 0,
            "interruptions": 0,  # sessions that ended without a run_stop, then resumed
        }
        self.link_down: dict[str, str] = {}
        self.sensor_status = "OK"
        self.hold_trouble: dict[int, list[str]] = {}
        self.classical: dict | None = None
        self.plan_axes: dict[int, str] = {}  # step → axis, from the journal's plan
        self.pace: tuple[tuple[datetime, float], tuple[datetime, float]] | None = None
        # the completed steps and the last t_s of each: what the classical snapshot was fitted to
        self._done_seen: tuple[frozenset[int], tuple[float, ...]] = (frozenset(), ())
        self._rounds_sent = 0
        self.expected: dict | None = None
        if self.program is not None:
            self.expected = calib.expected_sd(self.program)
        self.last_growth = self._clock()
        self.started_mono = self._clock()

    # ------------------------------------------------------------------ updating
    def update(self) -> bool:
        """Read what is new in the files; True if anything the page shows changed."""
        changed = False
        new = self.record.poll()
        if new is not None and "reset" in new:
            with self.lock:
                self._reset()
            return True
        evs = self.journal.poll()
        if self.raw.poll():
            changed = True
        if new is not None:
            self._add_rows(new)
            self.last_growth = self._clock()
            changed = True
        for ev in evs:
            self._on_event(ev)
            changed = True
        if self.map.poll():
            changed = True
        if self._recalibrate():  # also when a stall alone completes the last step
            changed = True
        with self.changed:
            self.version += 1 if changed else 0
            self.changed.notify_all()
        return changed

    def _add_rows(self, new: dict[str, np.ndarray]) -> None:
        t = new["t_s"]
        prev = self._cols["t_s"][-1] if self.n else None
        tt = t if prev is None else np.concatenate([[prev], t])
        d = np.diff(tt) * self.rate
        jumps = d > 1.5
        self.gaps += int(jumps.sum())
        self.lost += int(np.round(d[jumps]).sum() - jumps.sum())
        step = new["step"]
        for i in range(len(t)):
            s = step[i]
            s = int(s) if s == s else -1
            if self.runs and self.runs[-1][2] == s:
                self.runs[-1][1] = float(t[i])
            else:
                self.runs.append([float(t[i]), float(t[i]), s])
        with self.lock:
            self._cols = {c: np.concatenate([self._cols[c], new[c]]) for c in COLUMNS}
            self.n = len(self._cols["t_s"])

    def _on_event(self, ev: dict) -> None:
        if ev.get("event") == "_reset":
            return
        self.events.append(ev)
        kind = ev["event"]
        h = self.health
        t, utc = ev.get("t_s"), _utc(ev.get("utc"))
        if isinstance(t, int | float) and utc is not None:  # wall clock against sample clock
            first = self.pace[0] if self.pace else (utc, float(t))
            self.pace = (first, (utc, float(t)))
        if kind in (Event.RUN_START, Event.RESUME):
            self.pace = None  # a new session: its own pace
        if kind == Event.RUN_START:
            self.run_start = ev
            self.plan = list(ev.get("plan") or [])
            self.plan_axes = _plan_axes(self.plan)
            self.rate = float(ev.get("rate_hz") or 1.0)
            self.run_stop = None
            if self.plan and self.expected is None:
                prog = calib.program_from_plan(self.plan, ev.get("program") or "recorded")
                self.expected = calib.expected_sd(prog)
        elif kind == Event.RESUME:
            if self.run_stop is None and self.run_start is not None:
                h["interruptions"] += 1  # the session before ended without a word (kill -9)
            self.run_stop = None
            self.link_down.clear()
        elif kind == Event.STEP_START:
            self.current, self.hold = ev, None
        elif kind == Event.HOLD:
            self.hold = ev
        elif kind == Event.STEP_DONE:
            self.done_steps.add(int(ev["step"]))
        elif kind == Event.HOLD_LOST:
            h["hold_lost"] += 1
            self.hold = None
            self._trouble(ev, f"hold lost ({ev.get('state')})")
        elif kind == Event.HOLD_TIMEOUT:
            h["hold_timeouts"] += 1
            self._trouble(ev, "no HOLD within the hold timeout")
        elif kind == Event.FAULT:
            h["faults"] += 1
            self._trouble(ev, "platform FAULT")
        elif kind == Event.LINK_LOST:
            p = ev.get("port", "?")
            h["link_lost"][p] = h["link_lost"].get(p, 0) + 1
            self.link_down[p] = str(ev.get("reason", ""))
        elif kind == Event.RECONNECT:
            p = ev.get("port", "?")
            h["reconnects"][p] = h["reconnects"].get(p, 0) + 1
            self.link_down.pop(p, None)
        elif kind == Event.REPLY_TIMEOUT:
            h["reply_timeouts"] += 1
        elif kind == Event.SENSOR_STATUS:
            st = ev.get("status") or "OK"
            if st == "THERM":
                h["therm_episodes"] += 1
            elif st == "SAT":
                h["sat_episodes"] += 1
            self.sensor_status = st
        elif kind == Event.RUN_STOP:
            self.run_stop = ev

    def _trouble(self, ev: dict, what: str) -> None:
        step = ev.get("step")
        if step is not None:
            t = ev.get("t_s")
            at = f" at t = {t:.0f} s" if isinstance(t, int | float) else ""
            self.hold_trouble.setdefault(int(step), []).append(what + at)

    def complete_steps(self) -> set[int]:
        """Steps whose dwell is complete: journalled ``step_done``, or (no journal) a run of
        the step column that a later row closed, or a finished run's last one."""
        if self.run_start is not None:
            return set(self.done_steps)
        done = {r[2] for r in self.runs[:-1] if r[2] >= 0}
        if self.runs and self.runs[-1][2] >= 0:
            dwell = float(self.record.meta.get("program_dwell_s", "nan") or "nan")
            last = self.runs[-1]
            if last[1] - last[0] + 1.0 / self.rate >= dwell - 1e-9 or (
                self._clock() - self.last_growth > self.stall_s
            ):
                done.add(last[2])
        return done

    def _recalibrate(self) -> bool:
        """Refit the classical snapshot when a step has completed; True if it changed."""
        meta = self.record.meta
        if not self.n or "g_local_mgal" not in meta or self.record.problem:
            return False  # no calibration of a file that is no valid record (the alarm says why)
        done = self.complete_steps()
        # the fit changes only when a step completes, or a step a stall completed grows again
        seen = (frozenset(done), tuple(r[1] for r in self.runs if r[2] in done))
        if not done or seen == self._done_seen:
            return False
        self._done_seen = seen
        rec = calib.partial_record(meta, self.cols(), done, path=str(self.path))
        snap = calib.classical_snapshot(rec)
        if snap is None:
            return False
        with self.lock:
            self.classical = snap
        if snap["rounds_complete"] > self._rounds_sent:
            self._rounds_sent = snap["rounds_complete"]
            self.map.submit(self._rounds_sent, rec)
        return True

    # ------------------------------------------------------------------ reading
    def cols(self) -> dict[str, np.ndarray]:
        with self.lock:
            return dict(self._cols)

    def rows_since(self, start: int) -> dict:
        """Plot columns of rows ``start…`` (JSON-able; NaN as null)."""
        with self.lock:
            cols = {c: self._cols[c][start:] for c in _PLOT}
            n = self.n
        out: dict[str, Any] = {c: _jsonable(v, _DEC[c]) for c, v in cols.items()}
        out["start"] = start
        out["n"] = n
        return out

    def _step_info(self) -> dict | None:
        t_last = float(self._cols["t_s"][-1]) if self.n else None
        cur = self.current
        if cur is None:
            if not self.runs:
                return None
            r = self.runs[-1]
            phase = Phase.WAIT_HOLD if r[2] < 0 else Phase.HOLD_PENDING
            return {"index": r[2] if r[2] >= 0 else None, "phase": phase.shown}
        idx = int(cur["step"])
        phase = Phase.WAIT_HOLD
        done_n, need = 0, int(cur.get("dwell_samples") or 0)
        if idx in self.done_steps:
            phase, done_n = Phase.DONE, need
        elif self.hold is not None and t_last is not None:
            phase = Phase.DWELL
            done_n = min(need, round((t_last - float(self.hold["t_s"])) * self.rate) + 1)
        moving_s = None
        if phase is Phase.WAIT_HOLD and t_last is not None and cur.get("t_s") is not None:
            moving_s = t_last - float(cur["t_s"])
        return {
            "index": idx,
            "round": cur.get("round"),
            "kind": cur.get("kind"),
            "label": cur.get("label"),
            "phase": phase.shown,
            "dwell_done": done_n,
            "dwell_samples": need,
            "progress": done_n / need if need else None,
            "moving_s": moving_s,
        }

    def _remaining_s(self, step: dict | None) -> float | None:
        if not self.plan:
            return None
        if self.run_stop is not None:
            return 0.0 if not self.run_stop.get("exit_code") else None  # stopped: no time left
        if self.gone():
            return None  # nobody runs the program: when it ends is unknown
        left = 0.0
        cur = step["index"] if step else None
        for s in self.plan:
            i = int(s["index"])
            if i in self.done_steps:
                continue
            if i == cur and step and step["phase"] == Phase.DWELL.shown:
                left += (step["dwell_samples"] - step["dwell_done"]) / self.rate
            else:
                left += float(s["dwell_s"])
        return left

    def _dropped(self) -> dict:
        if self.run_stop is not None:
            summ = self.run_stop.get("summary") or {}
            d = summ.get("dropped") or {}
            return {p: {k: v for k, v in c.items() if v} for p, c in d.items()}
        return self.raw.dropped()

    def readings(self) -> dict | None:
        """The last row's readings (m1, m2, tilt X and Y, temperature; None where empty)."""
        if not self.n:
            return None
        out: dict = {"t_s": float(self._cols["t_s"][-1])}
        for c in _READINGS:
            v = float(self._cols[c][-1])
            out[c] = v if math.isfinite(v) else None
        return out

    def end(self, remaining_s: float | None) -> dict | None:
        """When the run ended (``run_stop``'s stamp) or, running, when it should end: now plus
        the program time left at the pace the journal shows (wall against sample clock)."""
        if self.run_stop is not None:
            at = _utc(self.run_stop.get("utc"))
            return None if at is None else {"utc": _iso(at), "estimated": False}
        if remaining_s is None or self.run_start is None:
            return None
        pace = 1.0
        if self.pace is not None:
            (u0, t0), (u1, t1) = self.pace
            if t1 - t0 >= PACE_MIN_S:
                pace = max((u1 - u0).total_seconds(), 0.0) / (t1 - t0)
        at = datetime.now(UTC) + timedelta(seconds=remaining_s * pace)
        return {"utc": _iso(at), "estimated": True}

    def hold_axes(self) -> dict[int, str]:
        """Axis ("x"/"y") of each step: the plan's, else the record's (``HoldTable.hold_axis``
        of the completed holds, in the classical snapshot)."""
        axes = dict((self.classical or {}).get("hold_axis") or {})
        axes.update(self.plan_axes)
        return axes

    def gone(self) -> bool:
        """The acquisition ended without journalling its end (killed, or the computer
        stopped): the run never stopped, the record is quiet and nobody holds the journal's
        lock. Unknown lock (no ``/proc/locks``): not gone (the stall alarm speaks)."""
        if self.run_stop is not None or self.run_start is None or self.quiet_s() < GONE_S:
            return False
        return journal_locked(self.journal.path) is False

    def finished(self) -> bool:
        """The run is over: its ``run_stop`` is journalled, or (no journal) the file is quiet."""
        if self.run_stop is not None:
            return True
        return self.run_start is None and self.n > 0 and self.quiet_s() > self.stall_s

    def alarms(self, step: dict | None) -> list[dict]:
        out: list[dict] = []
        if self.record.problem:
            out.append({"level": "alarm", "text": self.record.problem})
        if self.record.bad_rows:
            out.append(
                {
                    "level": "warn",
                    "text": f"{self.path}: {self.record.bad_rows} malformed row(s) skipped "
                    "(chekan calibrate names them)",
                }
            )
        gone = self.gone()
        running = self.run_stop is None and self.run_start is not None and not gone
        quiet = self._clock() - self.last_growth
        if gone:
            t = f" after t = {self._cols['t_s'][-1]:.0f} s" if self.n else ""
            out.append(
                {
                    "level": "alarm",
                    "text": f"the acquisition ended without journalling an end (killed, or the "
                    f"computer stopped): nothing is recorded{t}; continue the run with "
                    f"chekan acquire --resume {self.path}",
                }
            )
        if self.health["interruptions"]:
            k = self.health["interruptions"]
            out.append(
                {
                    "level": "warn",
                    "text": f"the acquisition was interrupted without an end {k} time(s) and "
                    f"resumed: {self.gaps} gap(s) in the record, {self.lost} sample(s) lost",
                }
            )
        if running and self.n and quiet > self.stall_s:
            out.append({"level": "alarm", "text": f"link stalled: no new sample for {quiet:.0f} s"})
        for p, why in self.link_down.items():
            if running:
                out.append({"level": "alarm", "text": f"{p} link down: {why}"})
        if step and step.get("index") is not None:
            i = step["index"]
            trouble = self.hold_trouble.get(i, [])
            ms = step.get("moving_s")
            if ms is not None and ms > MOVE_ALARM_S and running:
                trouble = [*trouble, f"no HOLD after {ms:.0f} s of sample clock"]
            if trouble and running and step["phase"] != Phase.DONE.shown:
                out.append(
                    {"level": "alarm", "text": f"step {i} cannot hold: " + "; ".join(trouble[-3:])}
                )
        if self.sensor_status == "THERM" and running:
            out.append({"level": "alarm", "text": "thermostat out of regulation (THERM flag)"})
        elif self.health["therm_episodes"]:
            n = self.health["therm_episodes"]
            out.append({"level": "warn", "text": f"{n} THERM episode(s): samples flagged"})
        if self.sensor_status == "SAT" and running:
            out.append({"level": "alarm", "text": "an image is off the CCD (SAT)"})
        if self.n:
            lo, hi = self._ccd_range()
            span = hi - lo
            for j, c in enumerate(("m1_pix", "m2_pix")):
                v = self._cols[c][-50:]
                v = v[np.isfinite(v)]
                if v.size == 0:
                    continue
                last = float(v[-1])
                if last < lo + CCD_MARGIN * span or last > hi - CCD_MARGIN * span:
                    out.append(
                        {
                            "level": "alarm",
                            "text": f"system {j + 1} reading {last:.1f} pix near the CCD end "
                            f"(usable {lo:g}…{hi:g})",
                        }
                    )
        if self.run_stop is not None and self.run_stop.get("exit_code"):
            out.append(
                {
                    "level": "alarm",
                    "text": f"run {self.run_stop.get('status')}: {self.run_stop.get('message')}",
                }
            )
        for e in self.map.errors[-2:]:
            out.append({"level": "warn", "text": f"running MAP failed: {e}"})
        if self.finished() and self.classical:
            for note in self.classical.get("notes") or []:
                out.append({"level": "warn", "text": note})
        return out

    def _ccd_range(self) -> tuple[float, float]:
        parts = self.record.meta.get("ccd_range_pix", "0 2048").replace(",", " ").split()
        try:
            lo, hi = (float(p) for p in parts)
            if math.isfinite(lo) and math.isfinite(hi) and lo < hi:
                return lo, hi
        except ValueError:
            pass
        return 0.0, 2048.0

    def status(self) -> dict:
        step = self._step_info()
        axes = self.hold_axes()
        if step and step.get("index") is not None:
            step["axis"] = axes.get(int(step["index"]))
        meta = self.record.meta
        remaining = self._remaining_s(step)
        if self.record.problem and not self.n:
            state = "not a record"
        elif self.run_stop is not None:
            state = self.run_stop.get("status", "stopped")
        elif self.gone():
            state = GONE
        elif self.run_start is None and not self.n:
            state = "waiting for the record"
        elif self.run_start is None:
            state = "record (no journal)"
        else:
            state = "running"
        h = dict(self.health)
        h["gaps"], h["lost_samples"] = self.gaps, self.lost
        h["dropped"] = self._dropped()
        h["bad_rows"] = self.record.bad_rows
        h["link_down"] = dict(self.link_down)
        rstop = (self.run_stop or {}).get("summary") or {}
        if rstop:
            h["gaps"], h["lost_samples"] = (
                rstop.get("gaps", self.gaps),
                rstop.get("lost_samples", self.lost),
            )
        return {
            "record": str(self.path),
            "meta": {
                k: meta.get(k)
                for k in ("serial", "program", "started", "g_local_mgal", "ccd_range_pix", "site")
            },
            "state": state,
            "n": self.n,
            "t_s": float(self._cols["t_s"][-1]) if self.n else None,
            "rate_hz": self.rate,
            "n_steps": len(self.plan) or None,
            "steps_done": len(self.done_steps) if self.run_start else None,
            "step": step,
            "remaining_s": remaining,
            "end": self.end(remaining),
            "stopped": None
            if not (self.run_stop and self.run_stop.get("exit_code"))
            else {
                "status": self.run_stop.get("status"),
                "exit_code": self.run_stop.get("exit_code"),
                "message": self.run_stop.get("message"),
            },
            "readings": self.readings(),
            "holds": [[*r, axes.get(r[2])] for r in self.runs if r[2] >= 0],
            "plan": [
                {
                    "index": s["index"],
                    "kind": s["kind"],
                    "label": s["label"],
                    "axis": self.plan_axes.get(int(s["index"])),
                }
                for s in self.plan
            ],
            "health": h,
            "alarms": self.alarms(step),
            "classical": self.classical,
            "map": list(self.map.results),
            "map_busy_round": self.map.busy_round,
            "expected_sd": self.expected,
            "quiet_s": round(self._clock() - self.last_growth, 1),
            "pid": os.getpid(),
        }


def _plan_axes(plan: list[dict]) -> dict[int, str]:
    """Axis of every planned step: a tilt's own; a level step takes the next tilt's (the
    last tilt's at the end), as ``HoldTable.hold_axis`` assigns level holds."""
    axes: dict[int, str] = {}
    pending: list[int] = []
    last = "y"
    for d in plan:
        i = int(d["index"])
        if d.get("kind") == "level":
            pending.append(i)
            continue
        last = step_axis(float(d.get("x_arcsec", 0.0)), float(d.get("y_arcsec", 0.0)))
        axes[i] = last
        for j in pending:
            axes[j] = last
        pending = []
    for j in pending:
        axes[j] = last
    return axes
