"""A hold's dwell is one uninterrupted run of rows on the sample clock: lost samples,
platform statuses gone stale and a kill -9 cut it, and it is served again in full
(the step machine and the resume, without devices)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import pytest

from hw.acquisition import Options, SampleClock
from hw.acquisition.plan import PlanStep
from hw.acquisition.resume import resume_state
from hw.acquisition.steps import StepMachine
from hw.errors import DwellCut
from hw.nmea import Plt

N = 10  # dwell samples at 1 Hz
STEP = PlanStep(0, 1, "tilt", "+1°", 0.0, 3600.0, float(N), 4.0, "y")


class Events:
    def __init__(self) -> None:
        self.got: list[tuple[str, dict]] = []

    def __call__(self, event: str, /, **fields: object) -> None:
        self.got.append((event, fields))

    def named(self, name: str) -> list[dict]:
        return [f for e, f in self.got if e == name]


class Bench:
    """The runner's sample path around a StepMachine: a status at every sample unless
    the platform is silent; one host second per sample."""

    def __init__(self, max_dwell_cuts: int = 100) -> None:
        self.ev = Events()
        self.now = 0.0
        self.rx = 0
        self.seq = -1
        self.clock = SampleClock(1.0, self.ev)
        opts = Options(max_dwell_cuts=max_dwell_cuts)
        self.m = StepMachine(opts, self.ev, self._send, clock=lambda: self.now)
        self.m.attach(self.clock)
        self.rows: list[tuple[int, int | None, tuple[float, float] | None]] = []

    def _send(self, st: PlanStep) -> int:
        self.rx += 1
        return self.rx

    def status(self, state: str = "HOLD") -> None:
        self.rx += 1
        self.m.on_status(self.rx, Plt("PLT", (), x=STEP.x_arcsec, y=STEP.y_arcsec, state=state))

    def sample(self, lost: int = 0, silent: bool = False) -> None:
        if not silent:
            self.status()
        self.seq += 1 + lost
        idx = self.clock.index(self.seq, 0)
        assert idx is not None
        step = self.m.on_sample(idx, first_row=not self.rows)
        self.rows.append((idx, step, self.m.angles_for_sample()))
        self.m.after_sample(idx, self.now)
        self.now += 1.0

    def last_run(self) -> list[int]:
        """Sample indices of the step's last run of rows (consecutive rows, no gap)."""
        run: list[int] = []
        for idx, step, _ in self.rows:
            if step is None:
                run = []
                continue
            run = [*run, idx] if run and idx == run[-1] + 1 else [idx]
        return run


def started() -> Bench:
    b = Bench()
    b.sample()  # the first row of a session belongs to no dwell
    b.m.begin(STEP)
    return b


def test_lost_samples_cut_the_dwell_and_it_is_served_again_in_full():
    b = started()
    for _ in range(5):
        b.sample()
    b.sample(lost=2)  # two samples lost mid-dwell
    assert b.rows[-1][1] is None  # the first row after the gap separates the runs
    while not b.m.step_done:
        b.sample()
        assert len(b.rows) < 40
    run = b.last_run()
    assert len(run) == N and run == list(range(run[0], run[0] + N))
    assert [r[1] for r in b.rows[1:6]] == [0] * 5  # the cut run stays in the record
    (cut,) = b.ev.named("hold_lost")
    assert (cut["state"], cut["lost"], cut["samples"]) == ("GAP", 2, 5)
    (done,) = b.ev.named("step_done")
    assert (done["samples"], done["lost"]) == (N, 0)
    assert done["t_s_first"] == run[0] and done["t_s_last"] == run[-1]
    assert b.m.stats.hold_restarts == 1 and len(b.ev.named("hold")) == 2


def test_a_silent_platform_cuts_the_dwell_until_it_holds_again():
    b = started()
    for _ in range(4):
        b.sample()
    for _ in range(8):  # no PLT for 8 s of sample clock and host time
        b.sample(silent=True)
    silent = [r for r in b.rows if r[2] is None]
    assert silent and all(step is None for _, step, _ in silent)  # unverified: no step
    (cut,) = b.ev.named("hold_lost")
    assert cut["state"] == "SILENT"
    while not b.m.step_done:
        b.sample()
        assert len(b.rows) < 40
    run = b.last_run()
    assert len(run) == N and run[0] > silent[-1][0]
    assert all(b.rows[i][2] is not None for i, r in enumerate(b.rows) if r[0] in run)


def test_a_dwell_cut_too_often_gives_up_after_writing_the_row():
    b = Bench(max_dwell_cuts=3)
    b.sample()
    b.m.begin(STEP)
    cuts = 0
    with pytest.raises(DwellCut, match=r"step 0 \(\+1°\).*cut short 3 times.*10 s"):
        for _ in range(10):
            for _ in range(3):
                b.sample()
            n = len(b.rows)
            try:
                b.sample(lost=1)
            finally:
                assert len(b.rows) == n + 1  # the row came before the error
            cuts += 1
    assert cuts == 2 and len(b.ev.named("hold_lost")) == 3


def test_a_fault_mid_dwell_is_dwelt_again_in_full():
    b = started()
    for _ in range(6):
        b.sample()
    b.status("FAULT")
    b.sample(silent=True)
    b.status("MOVE")
    b.sample(silent=True)
    while not b.m.step_done:
        b.sample()
        assert len(b.rows) < 40
    assert len(b.last_run()) == N
    assert b.ev.named("hold_lost")[0]["state"] == "FAULT"


def _record(path: Path, rows: list[tuple[int, int | None]]) -> None:
    head = "# format: chekan-record/1\n# serial: S1\n# g_local_mgal: 981922.05\n"
    lines = [f"{t},1000,1000,0,3600,{'' if s is None else s}" for t, s in rows]
    path.write_text(
        head + "t_s,m1_pix,m2_pix,tilt_x_arcsec,tilt_y_arcsec,step\n" + "\n".join(lines) + "\n"
    )
    start = {
        "event": "run_start",
        "utc": "2026-01-01T00:00:00Z",
        "plan": [
            asdict(STEP),
            {**asdict(STEP), "index": 1, "y_arcsec": 7200.0, "label": "+2°"},
        ],
        "rate_hz": 1.0,
        "sensor": {"serial": "S1"},
        "program": "p",
        "options": {},
    }
    sync = {"event": "sync", "utc": "2026-01-01T00:00:00Z", "seq_ref": 0, "t_ref": 0.0}
    Path(f"{path}.journal.jsonl").write_text(json.dumps(start) + "\n" + json.dumps(sync) + "\n")


def test_resume_runs_again_a_step_whose_last_run_has_a_gap(tmp_path):
    """Killed at the end of a dwell before its ``step_done``: the rows decide, and a gap
    inside them is no complete dwell."""
    rec = tmp_path / "rec.csv"
    gap = [(0, None)] + [(t, 0) for t in range(1, 6)] + [(t, 0) for t in range(8, 13)]
    _record(rec, gap)  # 10 rows of step 0 in a row, but 2 samples lost among them
    state, *_ = resume_state(rec)
    assert state is not None and state.first_step == 0 and state.done == set()
    whole = [(0, None)] + [(t, 0) for t in range(1, 6)] + [(6, None)]
    whole += [(t, 0) for t in range(7, 17)]
    _record(rec, whole)
    state, *_ = resume_state(rec)
    assert state is not None and state.first_step == 1 and state.done == {0}
