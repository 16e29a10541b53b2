"""Emulator of both devices (sensor and gyro-platform) on one device clock.

It follows ``docs/specs/serial-protocol.md``; the physics is
:class:`chekan.records.simulate.Instrument`:

- the platform slews at ``Truth.slew_deg_per_s`` (both axes reach the target
  together), settles for ``Truth.platform_settle_s``, then holds; it reports
  ``MOVE`` while slewing/settling, ``HOLD`` at the target;
- each angle sensor has its own errors (:mod:`hw.anglesensors`: a systematic
  δ(θ) = A·sin(2π·θ/P + φ) + s·θ, a random error per hold, a jitter per status line;
  the default platform has both, inside the 3″ bound): at a hold the REPORTED angle
  of each axis is ``commanded + jitter`` and the TRUE one ``commanded − δ(commanded)
  − e`` (the axis not tilted sits at its own offset −δ(0) − e); while slewing the
  true angle is the path minus δ(path); the instrument sees the TRUE (tx, ty)
  through the full geometry of ``record-format.md``;
  ``instrument.begin_hold()`` at HOLD, ``end_hold()`` when it moves or faults;
- the sensor samples the instrument at the true attitude every ``1/rate``
  device seconds; ``seq`` wraps at 65536 and keeps counting while nobody
  listens (or the port is stalled / gone); a ``PLT`` goes out at every sensor
  tick (at least once per device second) and at every state change.

``speed`` is device seconds per wall second (200: a 9 h program in under 3
min). ``speed=0`` runs as fast as the host reads: lock-stepped on the sensor
port (the next sample is made only when the host has read the previous one;
the platform port is waited for too unless nobody reads it), so nothing is
lost; device time stands still while nobody reads the sensor.
While the sensor port is stalled or gone in that mode, time runs at
``FAULT_PACE`` device seconds per wall second.

Faults (:mod:`hw.faults`) are drawn from their own seeded generator.
:class:`PtyEmulator` serves the two ports on pseudo-terminals with stable
symlinks; :class:`InProcessEmulator` on ``chekanemu://`` URLs.
"""

from __future__ import annotations

import contextlib
import math
import os
import random
import select
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from chekan.physics.units import ARCSEC_PER_RAD
from chekan.records.simulate import Instrument, Truth
from hw.anglesensors import PlatformSensors, default_sensors
from hw.endpoints import MemoryEndpoint, PtyEndpoint, memory_url, register, unregister
from hw.faults import FaultPlan
from hw.nmea import DEVICE_TYPES, SEQ_MOD, Query, SentenceParser, encode, format_number

RANGE_ARCSEC = 21600.0
FAULT_PACE = 100.0  # device s per wall s in lock-step mode while the sensor is silent
PLATFORM_PATIENCE_S = 0.5  # lock-step: a platform port unread that long is not waited for
FIRMWARE = "chekan-emu-1"
_NOISE = [b for b in range(256) if b not in (0x0A, 0x24)]  # no '\n', no '$'


@dataclass
class Hold:
    """One hold as the emulator made it (for checks against an estimator).

    ``readout_error_arcsec`` is the whole error (reported − true) of each sensor (X, Y),
    ``systematic_arcsec`` its systematic part; the true attitude is target − error.
    """

    t_s: float
    target_arcsec: tuple[float, float]
    readout_error_arcsec: tuple[float, float]
    systematic_arcsec: tuple[float, float] = (0.0, 0.0)

    @property
    def true_arcsec(self) -> tuple[float, float]:
        t, e = self.target_arcsec, self.readout_error_arcsec
        return t[0] - e[0], t[1] - e[1]

    def to_json(self) -> dict:
        return {
            "t_s": self.t_s,
            "target_arcsec": list(self.target_arcsec),
            "readout_error_arcsec": list(self.readout_error_arcsec),
            "systematic_arcsec": list(self.systematic_arcsec),
            "true_arcsec": list(self.true_arcsec),
        }


class PlatformModel:
    """Attitude and state of the gyro-platform as functions of device time (arcsec)."""

    def __init__(
        self, truth: Truth, rng: np.random.Generator, sensors: PlatformSensors | None = None
    ):
        self.truth = truth
        self.rng = rng
        self.sensors = sensors or default_sensors(
            truth.angle_error_sd_arcsec, truth.tilt_jitter_arcsec
        )
        self.state = "HOLD"
        self.target = (0.0, 0.0)
        self._start = (0.0, 0.0)
        self._t_cmd = 0.0
        self._t_arrive = 0.0
        self._t_hold = 0.0
        self._frozen = (0.0, 0.0)  # FAULT: the true attitude stays where it was
        self._frozen_read = (0.0, 0.0)  # … and so does the reading
        self.sys_err = self.sensors.systematic_arcsec(*self.target)
        self.err = self._draw_err()
        self.fault_active = False
        self.recommanded = False
        self.holds: list[Hold] = [Hold(0.0, self.target, self.err, self.sys_err)]

    def _draw_err(self) -> tuple[float, float]:
        """The whole error (reported − true) of each sensor at this hold: its systematic
        error at the target plus a random draw with its own sd."""
        z = self.rng.normal(0.0, 1.0, 2)
        sd = (self.sensors.x.sd, self.sensors.y.sd)
        return (
            self.sys_err[0] + float(z[0]) * sd[0],
            self.sys_err[1] + float(z[1]) * sd[1],
        )

    def _path(self, t: float) -> tuple[float, float]:
        if t >= self._t_arrive or self._t_arrive <= self._t_cmd:
            return self.target
        f = (t - self._t_cmd) / (self._t_arrive - self._t_cmd)
        return (
            self._start[0] + f * (self.target[0] - self._start[0]),
            self._start[1] + f * (self.target[1] - self._start[1]),
        )

    def true_attitude(self, t: float) -> tuple[float, float]:
        if self.state == "HOLD":
            return self.target[0] - self.err[0], self.target[1] - self.err[1]
        if self.state == "FAULT":
            return self._frozen
        x, y = self._path(t)
        dx, dy = self.sensors.systematic_arcsec(x, y)
        return x - dx, y - dy

    def reading(self, t: float) -> tuple[float, float]:
        """What the angle sensors report (without jitter)."""
        if self.state == "HOLD":
            return self.target
        if self.state == "FAULT":
            return self._frozen_read
        return self._path(t)

    def _move(self, t: float, x: float, y: float) -> None:
        self._start = self.reading(t)
        self.target = (x, y)
        dist = max(abs(x - self._start[0]), abs(y - self._start[1]))
        slew = max(self.truth.slew_deg_per_s, 1e-9) * 3600.0
        self._t_cmd = t
        self._t_arrive = t + dist / slew
        self._t_hold = self._t_arrive + self.truth.platform_settle_s
        self.state = "MOVE"

    def command(self, t: float, x: float, y: float) -> list[str]:
        """A TILT (or LEVEL) at device time ``t``; returns the state transitions."""
        if self.state == "FAULT":
            self.target = (x, y)
            if self.fault_active:
                self.recommanded = True
                return []
            self._move(t, x, y)
            return ["MOVE"]
        if self.state == "HOLD" and (x, y) == self.target:
            return []
        was = self.state
        self._move(t, x, y)
        return ["MOVE"] if was != "MOVE" else []

    def update(self, t: float, fault_active: bool) -> list[str]:
        """Advance to device time ``t``; returns the state transitions."""
        self.fault_active = fault_active
        if fault_active and self.state != "FAULT":
            self._frozen = self.true_attitude(t)
            self._frozen_read = self.reading(t)
            self.state = "FAULT"
            self.recommanded = False
            return ["FAULT"]
        if self.state == "FAULT" and not fault_active and self.recommanded:
            self.recommanded = False
            self._move(t, *self.target)
            return ["MOVE"]
        if self.state == "MOVE" and t >= self._t_hold:
            self.state = "HOLD"
            self.sys_err = self.sensors.systematic_arcsec(*self.target)
            self.err = self._draw_err()
            self.holds.append(Hold(t, self.target, self.err, self.sys_err))
            return ["HOLD"]
        return []


class Emulator:
    """Sensor + platform state machines on one device clock, writing to two endpoints."""

    def __init__(
        self,
        truth: Truth | None = None,
        *,
        seed: int = 0,
        speed: float = 1.0,
        faults: FaultPlan | None = None,
        seq_start: int = 0,
        model: str = "Shelf",
        platform_serial: str = "SIM-PLATFORM",
        clock: Callable[[], float] = time.monotonic,
        sensors: PlatformSensors | None = None,
    ):
        if speed < 0 or not math.isfinite(speed):
            raise ValueError(f"speed must be >= 0 (0: as fast as the host reads), not {speed}")
        self.truth = truth or Truth()
        self.rate = float(self.truth.sample_rate_hz)
        self.speed = float(speed)
        self.faults = faults or FaultPlan()
        self.model = model
        self.platform_serial = platform_serial
        self._clock = clock
        self.instrument = Instrument(self.truth, seed)
        self.platform = PlatformModel(self.truth, np.random.default_rng([seed, 1]), sensors)
        self.sensors = self.platform.sensors
        self._jitter_rng = np.random.default_rng([seed, 2])
        self._frng = random.Random(self.faults.seed if self.faults.seed is not None else seed)
        self.t = 0.0  # device time of the last tick
        self.ticks = 0
        self.sensor_seq = int(seq_start) % SEQ_MOD
        self.plt_seq = 0
        self.tilt_commands = 0
        self.stats: Counter[str] = Counter()
        self.events: list[tuple[float, str]] = []  # (device time, what) for tests and logs
        self.endpoints: dict[str, Any] = {}  # MemoryEndpoint or PtyEndpoint
        self._parsers = {p: SentenceParser(DEVICE_TYPES) for p in ("sensor", "platform")}
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stop = threading.Event()
        self._platform_deaf = False
        self._wall0 = clock()
        self._dev0 = 0.0
        n_sub = max(1, math.ceil(1.0 / self.rate - 1e-9))
        self._n_sub = n_sub  # status ticks per sensor sample (a PLT at least every second)
        self._dt = 1.0 / self.rate / n_sub
        self.instrument.equilibrium(0.0, 1e-9)  # compile the solver before the clock starts
        self.instrument.begin_hold()

    # ------------------------------------------------------------------ wiring
    def attach(self, port: str, endpoint) -> None:
        if port not in ("sensor", "platform"):
            raise ValueError(f"port must be 'sensor' or 'platform', not {port!r}")
        self.endpoints[port] = endpoint

    def wake(self) -> None:
        """Wake the loop (a memory endpoint got bytes from the host)."""
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self._wake_w, b"x")

    def stop(self) -> None:
        self._stop.set()
        self.wake()

    def close(self) -> None:
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    # ------------------------------------------------------------------ output
    def _live(self, port: str, t: float) -> bool:
        ep = self.endpoints.get(port)
        return ep is not None and ep.present and not self.faults.stalled(port, t)

    def _emit(self, port: str, line: bytes, stream: bool) -> None:
        t = self.t
        if not self._live(port, t):
            self.stats[f"{port}_silenced"] += 1
            return
        f = self.faults
        if stream and f.drop and self._frng.random() < f.drop:
            self.stats[f"{port}_dropped"] += 1
            return
        if f.badsum and self._frng.random() < f.badsum:
            star = line.rindex(b"*")
            bad = int(line[star + 1 : star + 3], 16) ^ self._frng.randrange(1, 256)
            line = line[: star + 1] + b"%02X" % bad + line[star + 3 :]
            self.stats[f"{port}_badsum"] += 1
        if f.garbage and self._frng.random() < f.garbage:
            line = self._garbage() + line
            self.stats[f"{port}_garbage"] += 1
        self._send(port, line)

    def _garbage(self) -> bytes:
        r = self._frng
        kind = r.randrange(4)
        n = r.randrange(1, 24)
        if kind == 0:  # binary noise (no end of line: it must not cut the next line)
            return bytes(r.choice(_NOISE) for _ in range(n))
        if kind == 1:  # a torn sentence
            return b"$GRV,1" + b"2" * r.randrange(4)
        if kind == 2:  # a line of noise
            return bytes(r.randrange(0x80, 0x100) for _ in range(n)) + b"\r\n"
        return b"~!" * (n // 2 + 1)

    def _send(self, port: str, data: bytes) -> None:
        ep = self.endpoints[port]
        lockstep = self.speed == 0 and port == "sensor"
        while data:
            n = ep.write(data)
            data = data[n:]
            self.stats[f"{port}_bytes"] += n
            if not data:
                return
            if not lockstep or not ep.present or self._stop.is_set():
                self.stats[f"{port}_overflow"] += 1  # nobody reads: the rest is lost
                return
            time.sleep(0.0005)  # not _poll: a reply must not cut into this line

    def _status(self, t: float) -> None:
        x, y = self.platform.reading(t)
        jx, jy = self.sensors.x.jitter, self.sensors.y.jitter
        if jx > 0 or jy > 0:
            zx, zy = self._jitter_rng.normal(0.0, 1.0, 2)
            x, y = x + float(zx) * jx, y + float(zy) * jy
        line = encode("PLT", self.plt_seq, f"{x:.2f}", f"{y:.2f}", self.platform.state)
        self.plt_seq = (self.plt_seq + 1) % SEQ_MOD
        self._emit("platform", line, stream=True)

    def _transitions(self, t: float, trans: list[str]) -> None:
        for tr in trans:
            self.events.append((t, tr))
            if tr == "HOLD":
                self.instrument.begin_hold()
            else:
                self.instrument.end_hold()

    # ------------------------------------------------------------------ commands
    def _now(self) -> float:
        """Device time of a command arriving now (between two ticks)."""
        if self.speed == 0:
            return self.t
        t = self._dev0 + (self._clock() - self._wall0) * self.speed
        return min(max(t, self.t), self.t + self._dt)

    def _handle(self, port: str, q: Query) -> None:
        self.stats[f"{port}_queries"] += 1
        if port == "sensor" and q.type == "GRQ":
            if q.key == "ID":
                reply = encode("GRA", "ID", self.truth.serial, self.model, FIRMWARE)
            elif q.key == "RATE":
                reply = encode("GRA", "RATE", format_number(self.rate))
            else:
                self.stats["unknown_query"] += 1
                return
            self._emit(port, reply, stream=False)
            return
        if port != "platform" or q.type != "PLQ":
            self.stats["unknown_query"] += 1
            return
        t = self._now()
        if q.key == "ID":
            self._emit(port, encode("PLA", "ID", self.platform_serial, FIRMWARE), stream=False)
            return
        if q.key == "LEVEL":
            self.events.append((t, "LEVEL"))
            self._transitions(t, self.platform.command(t, 0.0, 0.0))
            self._emit(port, encode("PLA", "LEVEL", "OK"), stream=False)
            self._status(t)
            return
        if q.key == "TILT":
            try:
                x, y = float(q.args[0]), float(q.args[1])
                if not (math.isfinite(x) and math.isfinite(y)):
                    raise ValueError
            except (IndexError, ValueError):
                self.stats["bad_tilt"] += 1
                return
            self.tilt_commands += 1
            err = self.faults.tilt_error(self.tilt_commands)
            if err is None and (abs(x) > RANGE_ARCSEC or abs(y) > RANGE_ARCSEC):
                err = "RANGE"
            if err is not None:
                self.events.append((t, f"TILT,ERR,{err}"))
                self._emit(port, encode("PLA", "TILT", "ERR", err), stream=False)
                return
            self.events.append((t, f"TILT {x:g} {y:g}"))
            self._transitions(t, self.platform.command(t, x, y))
            if self.tilt_commands not in self.faults.tilt_mutes:
                self._emit(port, encode("PLA", "TILT", "OK"), stream=False)
            self._status(t)
            return
        self.stats["unknown_query"] += 1

    def _poll(self, timeout: float) -> None:
        """Wait up to ``timeout`` wall seconds for host bytes and handle every query."""
        fds = [self._wake_r]
        for ep in self.endpoints.values():
            fd = ep.fileno()
            if fd is not None:
                fds.append(fd)
        try:
            select.select(fds, [], [], max(timeout, 0.0))
        except (OSError, ValueError):  # an fd closed under us (vanish): just go on
            time.sleep(min(max(timeout, 0.0), 0.01))
        with contextlib.suppress(BlockingIOError, OSError):
            os.read(self._wake_r, 4096)
        for port, ep in self.endpoints.items():
            data = ep.read()
            if data and not self.faults.vanished(port, self.t):
                for q in self._parsers[port].feed(data):
                    if isinstance(q, Query):
                        self._handle(port, q)

    # ------------------------------------------------------------------ clock
    def _schedules(self, t: float) -> None:
        for port, ep in self.endpoints.items():
            gone = self.faults.vanished(port, t)
            if gone and ep.present:
                ep.vanish()
                self.events.append((t, f"{port} vanished"))
            elif not gone and not ep.present:
                ep.restore()
                self.events.append((t, f"{port} back"))

    def _tick(self, t: float) -> None:
        self.t = t
        self._schedules(t)
        self._transitions(t, self.platform.update(t, self.faults.platform_fault(t)))
        self._status(t)
        if self.ticks % self._n_sub == 0:
            tx, ty = self.platform.true_attitude(t)
            m1, m2, temp = self.instrument.sample(t, tx / ARCSEC_PER_RAD, ty / ARCSEC_PER_RAD)
            lo, hi = 0.0, 2.0 * self.truth.m0_pix
            status = "THERM" if self.faults.therm(t) else "OK"
            if not (lo <= m1 <= hi and lo <= m2 <= hi):
                status = "SAT"
            f1 = "" if status == "SAT" else f"{m1:.4f}"
            f2 = "" if status == "SAT" else f"{m2:.4f}"
            line = encode("GRV", self.sensor_seq, f1, f2, f"{temp:.3f}", status)
            self.sensor_seq = (self.sensor_seq + 1) % SEQ_MOD
            self._emit("sensor", line, stream=True)
        self.ticks += 1

    def _wait_for(self, t_next: float) -> None:
        if self.speed > 0:
            deadline = self._wall0 + (t_next - self._dev0) / self.speed
            while not self._stop.is_set():
                left = deadline - self._clock()
                if left <= 0:
                    return
                self._poll(min(left, 0.05))
            return
        if self._live("sensor", t_next):
            ep = self.endpoints["sensor"]
            # bytes written to a pty reach the line discipline asynchronously (median
            # ~15 us, p99 a few ms): check twice before taking "nothing pending" as read
            for _ in range(2 if getattr(ep, "async_delivery", False) else 1):
                self._poll(0.0003)
                while ep.pending() > 0 and not self._stop.is_set():
                    self._poll(0.0003)
            self._wait_platform(t_next)
        else:
            deadline = self._clock() + (t_next - self.t) / FAULT_PACE
            while not self._stop.is_set() and (left := deadline - self._clock()) > 0:
                self._poll(min(left, 0.05))

    def _wait_platform(self, t_next: float) -> None:
        """Lock-step: keep the platform stream in step too, unless nobody reads it.

        A host that stops reading the platform port for ``PLATFORM_PATIENCE_S`` is
        taken as not listening (its lines then pile up and are lost, as on a real
        line) until it drains the port again.
        """
        ep = self.endpoints.get("platform")
        if ep is None or not self._live("platform", t_next):
            return
        pending = ep.pending()
        if pending == 0:
            self._platform_deaf = False
            return
        if self._platform_deaf:
            return
        deadline = self._clock() + PLATFORM_PATIENCE_S
        while not self._stop.is_set():
            self._poll(0.0005)
            now_pending = ep.pending()
            if now_pending == 0:
                return
            if now_pending < pending:
                pending, deadline = now_pending, self._clock() + PLATFORM_PATIENCE_S
            elif self._clock() > deadline:
                self._platform_deaf = True
                return

    def run(self, duration_s: float | None = None) -> None:
        """Run until :meth:`stop` (or ``duration_s`` wall seconds)."""
        end = None if duration_s is None else self._clock() + duration_s
        self._wall0, self._dev0 = self._clock(), self.t
        first = True
        while not self._stop.is_set():
            t_next = 0.0 if first and self.ticks == 0 else self.t + self._dt
            first = False
            self._wait_for(t_next)
            if self._stop.is_set():
                break
            self._tick(t_next)
            if end is not None and self._clock() >= end:
                break


class _Server:
    """Runs an :class:`Emulator` in a daemon thread; a context manager.

    The end of the thread is signalled by an Event (not ``Thread.join``: a join
    interrupted by Ctrl-C may later report a running thread as finished).
    """

    def __init__(self, emulator: Emulator | None = None, **kw):
        self.emulator = emulator or Emulator(**kw)
        self._thread: threading.Thread | None = None
        self._done = threading.Event()
        self.error: BaseException | None = None

    def _endpoints(self) -> dict[str, Any]:
        raise NotImplementedError

    def start(self, duration_s: float | None = None) -> _Server:
        for port, ep in self._endpoints().items():
            ep.create()
            self.emulator.attach(port, ep)
        self._done.clear()

        def main() -> None:
            try:
                self.emulator.run(duration_s)
            except BaseException as e:  # surfaced by stop()/tests
                self.error = e
                raise
            finally:
                self._done.set()

        self._thread = threading.Thread(target=main, name="hw-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the device clock, wait for the thread, then close the ports."""
        self.emulator.stop()
        if self._thread is not None:
            deadline = time.monotonic() + 30.0
            while not self._done.is_set() and time.monotonic() < deadline:
                self.emulator.stop()
                time.sleep(0.01)
            self._thread = None
        for ep in self._endpoints().values():
            ep.close()
        self.emulator.close()

    @property
    def running(self) -> bool:
        return self._thread is not None and not self._done.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the emulator thread to end; True if it ended."""
        if self._thread is None:
            return True
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._done.is_set():
            if deadline is not None and time.monotonic() >= deadline:
                return False
            time.sleep(0.02)  # Ctrl-C here leaves no half-released lock behind
        return True

    def __enter__(self):
        return self.start() if self._thread is None else self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class PtyEmulator(_Server):
    """Both devices on pseudo-terminals; ``sensor_link`` / ``platform_link`` are stable
    symlinks (e.g. ``/tmp/chekan-sensor``) to the ``/dev/pts/N`` devices."""

    def __init__(self, sensor_link: str | None, platform_link: str | None, **kw):
        super().__init__(**kw)
        self.sensor = PtyEndpoint("sensor", sensor_link)
        self.platform = PtyEndpoint("platform", platform_link)

    def _endpoints(self) -> dict[str, Any]:
        return {"sensor": self.sensor, "platform": self.platform}

    @property
    def sensor_url(self) -> str:
        return str(self.sensor.path)

    @property
    def platform_url(self) -> str:
        return str(self.platform.path)


class InProcessEmulator(_Server):
    """Both devices behind ``chekanemu://sensor?session=NAME`` and ``…platform…`` URLs."""

    def __init__(self, session: str = "default", **kw):
        super().__init__(**kw)
        self.session = session
        self.sensor = MemoryEndpoint("sensor", self.emulator.wake)
        self.platform = MemoryEndpoint("platform", self.emulator.wake)

    def _endpoints(self) -> dict[str, Any]:
        return {"sensor": self.sensor, "platform": self.platform}

    def start(self, duration_s: float | None = None) -> InProcessEmulator:
        register(self.session, self.sensor)
        register(self.session, self.platform)
        super().start(duration_s)
        return self

    def stop(self) -> None:
        super().stop()
        unregister(self.session)

    @property
    def sensor_url(self) -> str:
        return memory_url("sensor", self.session)

    @property
    def platform_url(self) -> str:
        return memory_url("platform", self.session)
