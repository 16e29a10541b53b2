"""Fault-injection plan of the emulator, written as text (``--faults``).

Items are separated by ``;`` (or white space); times are device seconds of the
sample clock, probabilities are per emitted line::

    garbage=0.01            random bytes (non-ASCII, stray '$', …) before a line
    badsum=0.01             a line with a wrong checksum
    drop=0.005              a stream line (GRV/PLT) not sent (GRV: a seq gap)
    stall=sensor@600+30     port silent from t=600 s for 30 s (sensor|platform|both)
    vanish=sensor@900+20    port disappears (pty closed, symlink removed), back after 20 s
    fault=1200+40           platform FAULT from 1200 s for 40 s, then waits for a TILT
    tilterr=BUSY@3          the 3rd TILT command is answered $PLA,TILT,ERR,BUSY
    tiltmute=2              the 2nd TILT command is obeyed but its reply is never sent
    therm=300+60            sensor status THERM (thermostat out of regulation)
    seed=7                  seed of the fault draws (default: the emulator's seed)

Everything random is drawn from a generator seeded by ``seed``: a plan plus a
seed gives the same faults at the same lines every run.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

PORTS = ("sensor", "platform")
TILT_REASONS = ("RANGE", "BUSY", "FAULT")

_WINDOW_RE = re.compile(r"(?:(?P<port>sensor|platform|both)@)?(?P<at>[\d.]+)\+(?P<dur>[\d.]+)")
_TILTERR_RE = re.compile(r"(?P<reason>[A-Z]+)@(?P<n>\d+)")


@dataclass(frozen=True)
class Window:
    """A time window ``[at, at + dur)`` of device seconds on one port."""

    port: str
    at: float
    dur: float

    def active(self, t: float) -> bool:
        return self.at <= t < self.at + self.dur


@dataclass
class FaultPlan:
    garbage: float = 0.0
    badsum: float = 0.0
    drop: float = 0.0
    stalls: list[Window] = field(default_factory=list)
    vanishes: list[Window] = field(default_factory=list)
    faults: list[Window] = field(default_factory=list)
    therms: list[Window] = field(default_factory=list)
    tilt_errors: dict[int, str] = field(default_factory=dict)
    tilt_mutes: set[int] = field(default_factory=set)
    seed: int | None = None

    def stalled(self, port: str, t: float) -> bool:
        return any(w.port == port and w.active(t) for w in self.stalls)

    def vanished(self, port: str, t: float) -> bool:
        return any(w.port == port and w.active(t) for w in self.vanishes)

    def platform_fault(self, t: float) -> bool:
        return any(w.active(t) for w in self.faults)

    def therm(self, t: float) -> bool:
        return any(w.active(t) for w in self.therms)

    def tilt_error(self, n: int) -> str | None:
        """Reason injected for the ``n``-th (1-based) TILT command, if any."""
        return self.tilt_errors.get(n)

    @property
    def empty(self) -> bool:
        return self == FaultPlan(seed=self.seed)


def _prob(key: str, v: str) -> float:
    try:
        p = float(v)
    except ValueError:
        p = -1.0
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"faults: {key}={v!r}: a probability between 0 and 1 is needed")
    return p


def _windows(key: str, v: str, need_port: bool) -> list[Window]:
    m = _WINDOW_RE.fullmatch(v)
    if not m or (need_port and not m["port"]):
        form = "PORT@AT+DUR (PORT: sensor, platform or both)" if need_port else "AT+DUR"
        raise ValueError(f"faults: {key}={v!r}: expected {form}, times in device seconds")
    at, dur = float(m["at"]), float(m["dur"])
    ports = PORTS if m["port"] in (None, "both") else (m["port"],)
    return [Window(p, at, dur) for p in ports]


def parse_faults(spec: str | None) -> FaultPlan:
    """Parse the ``--faults`` text (see the module docstring); ValueError names the item."""
    plan = FaultPlan()
    if not spec:
        return plan
    for item in re.split(r"[;\s]+", spec.strip()):
        if not item:
            continue
        key, sep, v = item.partition("=")
        if not sep:
            raise ValueError(f"faults: {item!r}: expected key=value")
        if key in ("garbage", "badsum", "drop"):
            setattr(plan, key, _prob(key, v))
        elif key == "stall":
            plan.stalls += _windows(key, v, need_port=True)
        elif key == "vanish":
            plan.vanishes += _windows(key, v, need_port=True)
        elif key == "fault":
            plan.faults += [w for w in _windows(key, v, need_port=False) if w.port == "platform"]
        elif key == "therm":
            plan.therms += [w for w in _windows(key, v, need_port=False) if w.port == "sensor"]
        elif key == "tilterr":
            m = _TILTERR_RE.fullmatch(v)
            if not m or m["reason"] not in TILT_REASONS or int(m["n"]) < 1:
                raise ValueError(
                    f"faults: tilterr={v!r}: expected REASON@N, REASON in {TILT_REASONS}, N >= 1"
                )
            plan.tilt_errors[int(m["n"])] = m["reason"]
        elif key == "tiltmute":
            if not v.isdigit() or int(v) < 1:
                raise ValueError(f"faults: tiltmute={v!r}: expected N >= 1 (the N-th TILT)")
            plan.tilt_mutes.add(int(v))
        elif key == "seed":
            try:
                plan.seed = int(v)
            except ValueError:
                raise ValueError(f"faults: seed={v!r} is not an integer") from None
        else:
            raise ValueError(
                f"faults: unknown item {key!r} (known: garbage, badsum, drop, stall, vanish, "
                "fault, tilterr, tiltmute, therm, seed)"
            )
    return plan
