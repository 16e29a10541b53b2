"""What a run is asked to do: the plan (program steps), the options, the exit codes."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

from chekan.physics.program import TiltProgram

EXIT_OK = 0
EXIT_DEVICE = 1  # the device refused (TILT,ERR) or misbehaved; or an I/O error
EXIT_CONFIG = 2  # bad arguments, existing record, wrong instrument on resume
EXIT_GAVE_UP = 3  # a link stayed down
EXIT_INTERRUPTED = 130


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
    axis: str = ""  # "x" or "y": the tilt's axis (level: its round's); "" read from x, y

    def __post_init__(self) -> None:
        if not self.axis:  # a journal written before steps carried their axis
            object.__setattr__(self, "axis", "x" if self.x_arcsec != 0.0 else "y")

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> PlanStep:
        """The step as stored in a ``run_start`` event (older journals: no ``axis``)."""
        return cls(**{f.name: d[f.name] for f in fields(cls) if f.name in d or f.name != "axis"})

    def dwell_samples(self, rate_hz: float) -> int:
        """Sample periods of the dwell (at least one)."""
        return max(1, round(self.dwell_s * rate_hz))


def plan_from_program(program: TiltProgram) -> list[PlanStep]:
    """The steps of ``program`` in order."""
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
            s.axis,
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
    max_dwell_cuts: int = 100  # a step's dwell cut short this often: give up (exit 3)
    recommand_s: float = 10.0  # sample clock: TILT re-sent this often while FAULT lasts
    angle_tol_arcsec: float = 60.0  # a HOLD counts if this close to the commanded angles
    stale_s: float = 5.0  # sample clock and host: older platform angles are not written
    fsync_interval_s: float = 2.0  # host
    level_wait_s: float = 60.0  # host: wait for the level HOLD at the end
    read_timeout_s: float = 0.05
    backoff_initial_s: float = 0.1
    backoff_max_s: float = 5.0

    def to_json(self) -> dict[str, Any]:
        """All fields (stored in the journal's ``run_start`` and ``resume`` events)."""
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Options:
        """Options from a journal event (unknown keys are ignored)."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})
