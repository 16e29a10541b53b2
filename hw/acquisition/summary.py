"""The outcome of a run: :class:`Summary` (returned, journaled in ``run_stop``, printed)."""

from __future__ import annotations

from dataclasses import dataclass, field

from hw.nmea import REASONS

PORTS = ("sensor", "platform")


@dataclass
class Summary:
    """Counts and status of one session (new or resumed) of a run."""

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
        """The human-readable table (first line: ``acquisition <status> (exit <code>)``)."""
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
