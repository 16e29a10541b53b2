"""The sample clock (seq → sample index through the wrap, gaps, stale lines, resume anchor)
and the step machine's phases, without devices."""

from __future__ import annotations

from hw.acquisition import Anchor, Phase, SampleClock
from hw.nmea import SEQ_MOD


class Events:
    def __init__(self) -> None:
        self.got: list[tuple[str, dict]] = []

    def __call__(self, event: str, /, **fields: object) -> None:
        self.got.append((event, fields))


def test_wrap_gap_duplicate_and_stale_line():
    ev = Events()
    c = SampleClock(2.0, ev)
    assert c.index(SEQ_MOD - 2, step=None) == 0 and ev.got[0][0] == "sync"
    assert c.index(SEQ_MOD - 1, step=None) == 1
    assert c.index(0, step=None) == 2  # through the wrap
    assert c.index(0, step=None) is None  # duplicate
    assert c.index(SEQ_MOD - 1, step=None) is None  # just behind: a stale line
    assert c.index(3, step=4) == 5  # two lost
    assert (c.stats.gaps, c.stats.lost_samples) == (1, 2)
    assert (c.stats.duplicates, c.stats.out_of_order) == (1, 1)
    name, gap = ev.got[-1]
    assert name == "gap" and gap["step"] == 4 and (gap["t_s_from"], gap["t_s_to"]) == (1.0, 2.5)
    assert "resumed" not in gap and c.t_last == 2.5


def test_resume_continues_after_the_anchor():
    ev = Events()
    c = SampleClock(1.0, ev, Anchor(idx=100, seq=SEQ_MOD - 1))
    assert c.index(2, step=7) == 103  # seq 0 and 1 lost across the restart
    (g, gap), (s, sync) = ev.got
    assert g == "gap" and gap["resumed"] is True and gap["step"] is None and gap["lost"] == 2
    assert s == "sync" and sync == {"seq_ref": 2, "t_ref": 103.0, "resumed": True}
    assert SampleClock(1.0, ev, Anchor(idx=100, seq=None)).index(9, step=None) == 101
    assert SampleClock(1.0, ev, Anchor(idx=100, seq=5)).index(5, step=None) is None


def test_phases_shown_in_progress():
    assert Phase.WAIT_HOLD.shown == "moving" and Phase.HOLD_PENDING.shown == "hold"
    assert Phase.LEVELING.shown == Phase.LEVEL.shown == "level" and Phase.DWELL.shown == "dwell"
