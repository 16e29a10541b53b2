"""Progress of an acquisition: what it is doing, and a one-line display of it."""

from __future__ import annotations

import shutil
import sys
import time
from dataclasses import dataclass
from typing import TextIO


@dataclass(frozen=True)
class Progress:
    """A snapshot; times are sample-clock seconds (the emulator may run faster than real time)."""

    step: int  # index of the current step (-1 before the first)
    n_steps: int
    round: int
    label: str
    phase: str  # "moving", "dwell", "level", …
    step_samples: int  # samples recorded in the current dwell
    dwell_samples: int
    t_s: float  # sample clock of the last sample
    left_s: float  # sample-clock seconds of dwell left in the program
    samples: int  # rows written in this session
    lost: int
    reconnects: int
    axis: str = ""  # the step's tilt axis, "x" or "y"


def format_progress(p: Progress) -> str:
    h, rem = divmod(int(max(p.left_s, 0)), 3600)
    m, s = divmod(rem, 60)
    label = f"{p.label} {p.axis.upper()}" if p.axis and p.label != "level" else p.label
    return (
        f"step {p.step + 1}/{p.n_steps} round {p.round} {label:>8} {p.phase:<6} "
        f"{p.step_samples}/{p.dwell_samples} samples  t={p.t_s:.0f} s  left {h}:{m:02d}:{s:02d}  "
        f"rows {p.samples} lost {p.lost} reconnects {p.reconnects}"
    )


class StatusLine:
    """Prints :class:`Progress` at most every ``interval_s`` (``\\r`` line on a terminal)."""

    def __init__(self, stream: TextIO | None = None, interval_s: float = 0.25):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.interval_s = interval_s if self.tty else max(interval_s, 10.0)
        self._last = -1e18
        self._width = 0

    def __call__(self, p: Progress) -> None:
        now = time.monotonic()
        if now - self._last < self.interval_s:
            return
        self._last = now
        text = format_progress(p)
        if self.tty:  # a line wider than the terminal would wrap, and "\r" redraw only its end
            text = text[: max(20, shutil.get_terminal_size().columns - 1)]
            pad = max(0, self._width - len(text))
            self.stream.write("\r" + text + " " * pad)
            self._width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def done(self) -> None:
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()
            self._width = 0
