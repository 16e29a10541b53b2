"""The emulated platform's two angle sensors and their errors (``chekan emulate --angle-errors``).

Each sensor (X: rotation about the platform X axis, Y: about Y) reports the true angle plus
its error ``δ = reported − true``:

    δ(θ) = A·sin(2π·θ/P + φ) + s·θ  +  e

- a **systematic** part, fixed for the platform: a periodic error of the angle (graduation
  and interpolation errors of the encoder: amplitude A, period P, phase φ; not a polynomial
  in θ, so a scale and offset cannot absorb it; its value at θ = 0 is the sensor's zero
  offset) plus a scale error ``s`` (ppm);
- a **random** part ``e`` ~ N(0, sd), drawn anew, independently per sensor, at every hold;
- a **jitter** N(0, jitter) on every status line (the reading's noise within a hold).

The platform's servo holds its *reading* at the commanded angle, so at a hold the reported
angle is the commanded one (± jitter) and the true angle is ``commanded − δ(commanded)``:
while the platform tilts about Y, the X axis sits at ``−δx(0) − eₓ`` (its own offset and
random error) and the X sensor reads 0 ± its own jitter, and vice versa.

The default platform (:func:`default_sensors`) is fixed (no draw), inside the 3″ bound of
the platform's specification over ±6°; ``random`` draws one inside it from the seed;
``none`` has no systematic error. Items ``x.amp=…`` etc. change one number (:func:`parse`).
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, replace

import numpy as np

BOUND_ARCSEC = 3.0  # the platform's specification: |systematic error| ≤ 3″
RANGE_DEG = 6.0  # the largest program angle (chekan.physics.program.MAX_ANGLE_DEG)
AXES = ("x", "y")
FIELDS = ("amp", "period_deg", "phase_deg", "scale_ppm", "sd", "jitter")
_ITEM_RE = re.compile(r"(?P<axis>[xy])\.(?P<field>[a-z_]+)=(?P<value>\S+)")


@dataclass(frozen=True)
class AngleSensor:
    """One angle sensor's errors, arcsec (see the module docstring)."""

    amp: float = 0.0  # A: amplitude of the periodic error, arcsec
    period_deg: float = 1.0  # P
    phase_deg: float = 0.0  # φ
    scale_ppm: float = 0.0  # s, 1e-6
    sd: float = 0.0  # random error per hold, arcsec
    jitter: float = 0.0  # noise per status line, arcsec

    def systematic(self, theta_arcsec: float | np.ndarray) -> np.ndarray:
        """δ_sys(θ) = A·sin(2π·θ/P + φ) + s·θ, arcsec, at the angles θ in arcsec."""
        th = np.asarray(theta_arcsec, dtype=float)
        arg = 2.0 * np.pi * th / (self.period_deg * 3600.0) + np.deg2rad(self.phase_deg)
        return self.amp * np.sin(arg) + self.scale_ppm * 1e-6 * th

    def systematic_arcsec(self, theta_arcsec: float) -> float:
        """:meth:`systematic` at one angle."""
        return float(self.systematic(np.float64(theta_arcsec)))

    def max_systematic_arcsec(self, range_deg: float = RANGE_DEG) -> float:
        """max |δ_sys| over ±``range_deg`` (on a 5″ grid)."""
        grid = np.linspace(-range_deg * 3600.0, range_deg * 3600.0, 8641)
        return float(np.max(np.abs(self.systematic(grid))))

    def describe(self) -> str:
        sys_part = (
            f"{self.amp:g}″·sin(2π·θ/{self.period_deg:g}° + {self.phase_deg:g}°) "
            f"{'+' if self.scale_ppm >= 0 else '−'} {abs(self.scale_ppm):g} ppm·θ "
            f"(max {self.max_systematic_arcsec():.2f}″ over ±{RANGE_DEG:g}°)"
        )
        return f"{sys_part}, random {self.sd:g}″ per hold, jitter {self.jitter:g}″"


@dataclass(frozen=True)
class PlatformSensors:
    """Both angle sensors of the platform; ``name`` says where they came from."""

    x: AngleSensor
    y: AngleSensor
    name: str = "default"

    def sensor(self, axis: str) -> AngleSensor:
        return self.x if axis == "x" else self.y

    def systematic_arcsec(self, x_arcsec: float, y_arcsec: float) -> tuple[float, float]:
        """(δx, δy) systematic errors at the reading (x, y), arcsec."""
        return self.x.systematic_arcsec(x_arcsec), self.y.systematic_arcsec(y_arcsec)

    def to_json(self) -> dict:
        return {"name": self.name, "x": asdict(self.x), "y": asdict(self.y)}

    def describe(self) -> str:
        return f"angle sensors ({self.name}): X {self.x.describe()}; Y {self.y.describe()}"


def default_sensors(sd_arcsec: float = 2.0, jitter_arcsec: float = 0.3) -> PlatformSensors:
    """The default platform: each sensor its own periodic error and scale error (fixed
    numbers, |δ_sys| ≤ 2.4″ over ±6°), random error ``sd_arcsec`` per hold and jitter."""
    return PlatformSensors(
        x=AngleSensor(1.0, 2.3, 200.0, -70.0, sd_arcsec, jitter_arcsec),
        y=AngleSensor(1.2, 1.5, 40.0, 50.0, sd_arcsec, jitter_arcsec),
        name="default",
    )


def no_systematic(sd_arcsec: float = 2.0, jitter_arcsec: float = 0.3) -> PlatformSensors:
    """Sensors without systematic error (random error and jitter kept)."""
    s = AngleSensor(0.0, 1.0, 0.0, 0.0, sd_arcsec, jitter_arcsec)
    return PlatformSensors(s, s, name="none")


def random_sensors(
    seed: int, sd_arcsec: float = 2.0, jitter_arcsec: float = 0.3
) -> PlatformSensors:
    """Sensors drawn from ``seed`` (own stream): A ~ U(0.3, 1.5)″, P ~ U(0.5, 4)°, φ ~ U(0, 360)°,
    s ~ U(−60, 60) ppm per sensor, so |δ_sys| ≤ 1.5″ + 60 ppm·6° < 2.8″ (inside the bound)."""
    rng = np.random.default_rng([int(seed), 0xA5E])

    def one() -> AngleSensor:
        a, p, f, s = rng.uniform((0.3, 0.5, 0.0, -60.0), (1.5, 4.0, 360.0, 60.0))
        return AngleSensor(float(a), float(p), float(f), float(s), sd_arcsec, jitter_arcsec)

    return PlatformSensors(one(), one(), name=f"random, seed {seed}")


def parse(
    text: str, *, seed: int = 0, sd_arcsec: float = 2.0, jitter_arcsec: float = 0.3
) -> PlatformSensors:
    """``--angle-errors``: a base (``default``, ``none``, ``random``; default first) then
    items ``AXIS.FIELD=VALUE`` (AXIS x or y; FIELD one of :data:`FIELDS`), separated by
    ``;`` or white space. ValueError names the item and what is wrong."""
    items = [t for t in re.split(r"[;\s]+", text.strip()) if t]
    base = "default"
    if items and "=" not in items[0]:
        base = items.pop(0)
    if base == "default":
        sensors = default_sensors(sd_arcsec, jitter_arcsec)
    elif base == "none":
        sensors = no_systematic(sd_arcsec, jitter_arcsec)
    elif base == "random":
        sensors = random_sensors(seed, sd_arcsec, jitter_arcsec)
    else:
        raise ValueError(
            f"--angle-errors: {base!r}: the first item is default, none or random, "
            "or an item AXIS.FIELD=VALUE"
        )
    changes: dict[str, dict[str, float]] = {"x": {}, "y": {}}
    for item in items:
        m = _ITEM_RE.fullmatch(item)
        if not m:
            raise ValueError(
                f"--angle-errors: {item!r}: expected AXIS.FIELD=VALUE, AXIS x or y, "
                f"FIELD one of {', '.join(FIELDS)}"
            )
        field, value = m["field"], m["value"]
        if field not in FIELDS:
            raise ValueError(
                f"--angle-errors: {item!r}: unknown field {field!r}; one of {', '.join(FIELDS)}"
            )
        try:
            v = float(value)
        except ValueError:
            v = math.nan
        if not math.isfinite(v) or abs(v) > 1e6:
            raise ValueError(f"--angle-errors: {item!r}: {value!r} is not a finite number")
        if field == "period_deg" and v <= 0:
            raise ValueError(f"--angle-errors: {item!r}: the period must be positive")
        if field in ("amp", "sd", "jitter") and v < 0:
            raise ValueError(f"--angle-errors: {item!r}: {field} must not be negative")
        changes[m["axis"]][field] = v
    if any(changes.values()):
        sensors = PlatformSensors(
            replace(sensors.x, **changes["x"]),
            replace(sensors.y, **changes["y"]),
            name=f"{sensors.name}, changed",
        )
    return sensors
