"""Tilt programs: the sequence of platform attitudes, dwell and settling times.

The paper's program (``default_program``): angles ±1°50′, ±2°30′, ±3°10′, ±3°40′,
±4°10′, ±4°30′, ±4°50′, ±5°10′ about the platform Y axis, chosen so that Δg grows by
about 500 mGal from one angle to the next; per round the steps are
level, +θ₁, −θ₁, …, +θ₈, −θ₈, level; two rounds; 900 s per step, the first 300 s
settling (36 steps, 9 h).

A program file is TOML::

    name = "paper"
    angles = ["1°50'", "2°30'", "3°10'"]   # magnitudes, DMS text or decimal degrees
    axis = "y"            # platform axis of the tilt: "y" (calibration), "x", or "xy"
                          # ("xy": rounds alternate, odd rounds about Y, even about X)
    # round_axes = ["y", "x", "x", "y"]  # instead of axis: the axis of each round, one per
                          # round (as many as ``rounds``, which it sets when absent);
                          # a file gives axis or round_axes, not both
    order = "+-"          # per angle: "+-", "-+", or "alternate" (+- in odd rounds, -+ in even)
    sequence = "ascending" # "ascending", "descending", "as-given", "zigzag" (asc, then desc)
    dwell_s = 900
    settle_s = 300
    rounds = 2
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from chekan.errors import ProgramError
from chekan.physics.units import ARCSEC_PER_RAD, format_dms, parse_angle_deg

MAX_ANGLE_DEG = 6.0
AXES = ("y", "x", "xy")  # "xy": rounds alternate between Y (odd) and X (even)
PAPER_ANGLES = ("1°50'", "2°30'", "3°10'", "3°40'", "4°10'", "4°30'", "4°50'", "5°10'")


@dataclass(frozen=True)
class Step:
    """One step of a program: hold the platform at (tilt_x, tilt_y) for ``dwell_s``."""

    index: int
    round: int  # 1-based
    kind: str  # "level" or "tilt"
    angle_index: int  # 0-based index into the program's angles; -1 for level
    sign: int  # +1, -1; 0 for level
    tilt_x_rad: float
    tilt_y_rad: float
    dwell_s: float
    settle_s: float
    axis: str = "y"  # the axis (and angle sensor) of the step; level: its round's axis

    @property
    def tilt_x_arcsec(self) -> float:
        return self.tilt_x_rad * ARCSEC_PER_RAD

    @property
    def tilt_y_arcsec(self) -> float:
        return self.tilt_y_rad * ARCSEC_PER_RAD

    @property
    def theta_rad(self) -> float:
        """Signed commanded tilt about the program axis."""
        return self.tilt_y_rad if self.tilt_x_rad == 0.0 else self.tilt_x_rad

    def label(self) -> str:
        if self.kind == "level":
            return "level"
        return format_dms(np.rad2deg(self.theta_rad), sign="always")


@dataclass(frozen=True)
class TiltProgram:
    """An ordered list of steps plus the description it was built from."""

    name: str
    angles_rad: tuple[float, ...]  # magnitudes, as given
    axis: str
    order: str
    sequence: str
    dwell_s: float
    settle_s: float
    rounds: int
    steps: tuple[Step, ...] = field(repr=False)
    round_axes: tuple[str, ...] = ()
    """The axis ("y" or "x") of each round; ``axis`` summarises them ("xy": both axes)."""
    axes_given: bool = False  # True: the program was given per round (``round_axes``)
    angles_deg: tuple[float, ...] = ()  # the magnitudes as given, degrees (a file writes these)

    @property
    def duration_s(self) -> float:
        return float(sum(s.dwell_s for s in self.steps))

    @property
    def n_steps(self) -> int:
        return len(self.steps)

    def describe(self) -> str:
        angs = ", ".join(format_dms(np.rad2deg(a), sign="pm") for a in self.angles_rad)
        about = self.axes_text()
        return (
            f"{self.name}: {self.rounds} round(s) × {len(self.angles_rad)} angles ({angs}) about "
            f"{about}, order {self.order}, dwell {self.dwell_s:g} s "
            f"(settle {self.settle_s:g} s), {self.n_steps} steps, {self.duration_s / 3600:.2f} h"
        )

    @property
    def tilt_axes(self) -> tuple[str, ...]:
        """The axes its rounds tilt about, Y first: ("y",), ("x",) or ("y", "x")."""
        return tuple(a for a in ("y", "x") if a in self.round_axes)

    def axes_text(self) -> str:
        """The axes of the rounds in words: "Y", "X", "Y and X (alternate rounds)", or the
        axis of each round ("Y, X, X, Y") for a program given per round."""
        if self.axes_given and len(set(self.round_axes)) > 1:
            return "rounds " + ", ".join(a.upper() for a in self.round_axes)
        return _axis_text(self.axis)


def round_axis(axis: str, rnd: int) -> str:
    """The tilt axis of round ``rnd`` (1-based): ``axis`` itself, or for "xy" Y in odd
    rounds and X in even ones."""
    if axis == "xy":
        return "y" if rnd % 2 else "x"
    return axis


def _axis_text(axis: str) -> str:
    return "Y and X (alternate rounds)" if axis == "xy" else axis.upper()


def build_program(
    angles_deg,
    *,
    name: str = "custom",
    axis: str = "y",
    order: str = "+-",
    sequence: str = "ascending",
    dwell_s: float = 900.0,
    settle_s: float = 300.0,
    rounds: int | None = None,
    round_axes=None,
    source: str = "<program>",
) -> TiltProgram:
    """Build and validate a program; errors name ``source`` and the offending value.

    ``round_axes``: the axis ("y"/"x") of each round, one per round, instead of ``axis``
    (``axis`` then summarises them: "y", "x", or "xy" for both). ``rounds`` defaults to
    one per entry of ``round_axes``, else 2."""
    if rounds is None:
        given = isinstance(round_axes, list | tuple) and len(round_axes) > 0
        rounds = len(round_axes) if given else 2
    angles = [float(a) for a in angles_deg]
    if not angles:
        raise ProgramError(f"{source}: empty program (no angles)")
    for a in angles:
        if not np.isfinite(a) or a <= 0:
            raise ProgramError(f"{source}: angle {a:g}° must be a positive magnitude")
        if a > MAX_ANGLE_DEG:
            raise ProgramError(
                f"{source}: angle {format_dms(a)} ({a:.4f}°) is beyond the {MAX_ANGLE_DEG:g}° limit"
            )
    if axis not in AXES:
        raise ProgramError(f"{source}: axis must be 'x', 'y' or 'xy', not {axis!r}")
    if order not in ("+-", "-+", "alternate"):
        raise ProgramError(f"{source}: order must be '+-', '-+' or 'alternate', not {order!r}")
    if sequence not in ("ascending", "descending", "as-given", "zigzag"):
        raise ProgramError(
            f"{source}: sequence must be ascending, descending, as-given or zigzag, "
            f"not {sequence!r}"
        )
    if not np.isfinite(dwell_s) or dwell_s <= 0:
        raise ProgramError(f"{source}: dwell_s must be positive, not {dwell_s:g}")
    if not np.isfinite(settle_s) or settle_s < 0:
        raise ProgramError(f"{source}: settle_s must be zero or positive, not {settle_s:g}")
    if settle_s >= dwell_s:
        raise ProgramError(
            f"{source}: settle_s ({settle_s:g}) must be shorter than dwell_s ({dwell_s:g})"
        )
    if int(rounds) != rounds or rounds < 1:
        raise ProgramError(f"{source}: rounds must be a positive integer, not {rounds!r}")
    if round_axes is None:
        per_round = tuple(round_axis(axis, r) for r in range(1, int(rounds) + 1))
    else:
        per_round = _checked_round_axes(round_axes, int(rounds), source)
        axis = per_round[0] if len(set(per_round)) == 1 else "xy"

    idx = list(range(len(angles)))
    if sequence == "ascending":
        idx.sort(key=lambda i: angles[i])
    elif sequence == "descending":
        idx.sort(key=lambda i: -angles[i])
    steps: list[Step] = []

    def add(rnd: int, kind: str, ai: int, sign: int) -> None:
        th = sign * np.deg2rad(angles[ai]) if kind == "tilt" else 0.0
        ax = per_round[rnd - 1]
        tx, ty = (0.0, th) if ax == "y" else (th, 0.0)
        steps.append(
            Step(len(steps), rnd, kind, ai, sign, tx, ty, float(dwell_s), float(settle_s), ax)
        )

    for rnd in range(1, int(rounds) + 1):
        seq = idx
        if sequence == "zigzag" and rnd % 2 == 0:
            seq = idx[::-1]
        signs = (1, -1)
        if order == "-+" or (order == "alternate" and rnd % 2 == 0):
            signs = (-1, 1)
        add(rnd, "level", -1, 0)
        for ai in seq:
            for s in signs:
                add(rnd, "tilt", ai, s)
        add(rnd, "level", -1, 0)
    return TiltProgram(
        name=name,
        angles_rad=tuple(float(np.deg2rad(a)) for a in angles),
        axis=axis,
        order=order,
        sequence=sequence,
        dwell_s=float(dwell_s),
        settle_s=float(settle_s),
        rounds=int(rounds),
        steps=tuple(steps),
        round_axes=per_round,
        axes_given=round_axes is not None,
        angles_deg=tuple(angles),
    )


def _checked_round_axes(round_axes, rounds: int, source: str) -> tuple[str, ...]:
    """``round_axes`` as a tuple of "y"/"x", one per round; anything else is an error."""
    if isinstance(round_axes, str) or not isinstance(round_axes, list | tuple):
        raise ProgramError(
            f'{source}: round_axes must be a list of "y"/"x", one per round, not {round_axes!r}'
        )
    for i, a in enumerate(round_axes):
        if a not in ("y", "x"):
            raise ProgramError(f"{source}: round_axes[{i}] must be 'y' or 'x', not {a!r}")
    if len(round_axes) != rounds:
        raise ProgramError(
            f"{source}: round_axes has {len(round_axes)} entries for {rounds} round(s): "
            "give one axis per round"
        )
    return tuple(round_axes)


def default_program(**overrides) -> TiltProgram:
    """The paper's program: 8 angles, 2 rounds, 900 s dwell of which 300 s settle (9 h)."""
    kw: dict[str, Any] = dict(name="paper", dwell_s=900.0, settle_s=300.0, rounds=2)
    kw.update(overrides)
    return build_program([parse_angle_deg(a) for a in PAPER_ANGLES], **kw)


_KEYS = {
    "name",
    "angles",
    "axis",
    "round_axes",
    "order",
    "sequence",
    "dwell_s",
    "settle_s",
    "rounds",
}


def load_program(path: str | Path) -> TiltProgram:
    """Read a TOML program file (see the module docstring); errors name the file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ProgramError(f"{path}: no such program file") from None
    except tomllib.TOMLDecodeError as e:
        raise ProgramError(f"{path}: not valid TOML: {e}") from None
    unknown = set(data) - _KEYS
    if unknown:
        raise ProgramError(f"{path}: unknown key(s) {sorted(unknown)}; allowed: {sorted(_KEYS)}")
    if "angles" not in data or not isinstance(data["angles"], list):
        raise ProgramError(f"{path}: 'angles' must be a list of angles")
    angles = []
    for i, a in enumerate(data["angles"]):
        try:
            angles.append(abs(parse_angle_deg(str(a))))
        except ValueError as e:
            raise ProgramError(f"{path}: angles[{i}]: {e}") from None
    if "axis" in data and "round_axes" in data:
        raise ProgramError(
            f"{path}: give either axis or round_axes (the axis of each round), not both"
        )
    kw: dict[str, Any] = {
        k: data[k] for k in ("axis", "round_axes", "order", "sequence", "rounds") if k in data
    }
    for k in ("dwell_s", "settle_s"):
        if k in data:
            if not isinstance(data[k], int | float) or isinstance(data[k], bool):
                raise ProgramError(f"{path}: {k} must be a number, not {data[k]!r}")
            kw[k] = float(data[k])
    return build_program(angles, name=str(data.get("name", path.stem)), source=str(path), **kw)
