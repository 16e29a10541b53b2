"""The sample clock: ``seq`` → sample index → ``t_s``, through the 16-bit wrap.

A jump in ``seq`` is a gap (``t_s`` jumps with it, the lost samples are counted
and journaled); a repeated ``seq`` is a duplicate and a ``seq`` just behind the
last one a stale line (both ignored). The first sample of a session anchors the
clock (a ``sync`` event): at 0 for a new run, strictly after the last complete
row of the record for a resumed one (through ``seq`` when the journal kept the
anchor, else right after it).
"""

from __future__ import annotations

from dataclasses import dataclass

from hw.acquisition.recorder import EventLog
from hw.events import Event
from hw.nmea import SEQ_MOD

BACKWARDS_WINDOW = 64  # a seq this close behind the last one is a stale line, not a 65 k gap


@dataclass(frozen=True)
class Anchor:
    """Where a resumed run's record ends: the last complete row's sample index and ``seq``."""

    idx: int | None
    seq: int | None


@dataclass
class ClockStats:
    """What the clock counted in this session."""

    gaps: int = 0  # seq jumps
    lost_samples: int = 0  # samples missing in those jumps
    duplicates: int = 0
    out_of_order: int = 0


class SampleClock:
    """Sample indices of the sensor's ``seq`` numbers (owns its state and :class:`ClockStats`)."""

    def __init__(self, rate_hz: float, journal: EventLog, resumed_from: Anchor | None = None):
        self.rate = rate_hz
        self._journal = journal
        self._resumed_from = resumed_from
        self.stats = ClockStats()
        self.last_seq: int | None = None
        self.last_idx: int | None = None

    @property
    def started(self) -> bool:
        """Whether the first sample of this session has been placed."""
        return self.last_seq is not None

    @property
    def t_last(self) -> float | None:
        """``t_s`` of the last sample placed (None before the first)."""
        return None if self.last_idx is None else self.last_idx / self.rate

    def index(self, seq: int, step: int | None) -> int | None:
        """Sample index of ``seq``; None for a duplicate or stale line.

        ``step`` is the step being run (it goes into a gap's journal event).
        """
        if self.last_seq is not None and self.last_idx is not None:
            return self._advance(self.last_idx, self.last_seq, seq, step=step)
        anchor = self._resumed_from
        if anchor is None or anchor.idx is None:
            idx = 0
        elif anchor.seq is None:
            idx = anchor.idx + 1  # no seq anchor in the journal: continue right after
        else:
            advanced = self._advance(anchor.idx, anchor.seq, seq, step=None, across_resume=True)
            if advanced is None:
                return None
            idx = advanced
        self.last_seq, self.last_idx = seq, idx
        self._journal(
            Event.SYNC, seq_ref=seq, t_ref=idx / self.rate, resumed=self._resumed_from is not None
        )
        return idx

    def _advance(
        self,
        from_idx: int,
        from_seq: int,
        seq: int,
        *,
        step: int | None,
        across_resume: bool = False,
    ) -> int | None:
        """The index of ``seq`` after (``from_idx``, ``from_seq``): counts and journals a gap.

        ``across_resume``: from the record's last row to a resumed session's first sample
        (no stale-line window there; the gap event says ``resumed``).
        """
        s = self.stats
        d = (seq - from_seq) % SEQ_MOD
        if d == 0:
            s.duplicates += 1
            return None
        if not across_resume and d > SEQ_MOD - BACKWARDS_WINDOW:
            s.out_of_order += 1
            return None
        idx = from_idx + d
        if d > 1:
            s.gaps += 1
            s.lost_samples += d - 1
            resumed = {"resumed": True} if across_resume else {}
            self._journal(
                Event.GAP,
                seq_from=from_seq,
                seq_to=seq,
                lost=d - 1,
                t_s_from=from_idx / self.rate,
                t_s_to=idx / self.rate,
                step=step,
                **resumed,
            )
        self.last_seq, self.last_idx = seq, idx
        return idx
