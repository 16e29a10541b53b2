"""Resume: where a killed or interrupted run stands (journal + record); continuing it is
:func:`hw.acquisition.start.resume`.

Completed steps are kept; the first unfinished step is re-run from its ``TILT``
(its partial rows stay; a step whose rows end in an uninterrupted run of its whole dwell
counts as done, though its ``step_done`` was not journaled); ``t_s`` continues strictly
after the last complete row, through ``seq`` (the journal's last ``sync`` event keeps
the ``seq`` ↔ ``t_s`` anchor).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from chekan.errors import ChekanError
from chekan.records import Record, read_record
from hw.acquisition.clock import Anchor
from hw.acquisition.plan import PlanStep
from hw.events import Event
from hw.journal import journal_path, read_journal
from hw.nmea import SEQ_MOD


@dataclass
class ResumeState:
    """What a resumed session continues from."""

    first_step: int
    done: set[int]
    last_idx: int | None  # sample index of the last complete row
    last_seq: int | None  # its seq
    rate_hz: float
    serial: str

    @property
    def anchor(self) -> Anchor:
        """The sample clock's anchor: the record's last complete row."""
        return Anchor(self.last_idx, self.last_seq)

    def check_instrument(self, path: Path, serial: str, rate_hz: float) -> None:
        """Refuse to continue the record with another sensor or another sample rate."""
        if serial != self.serial:
            raise ChekanError(
                f"{path}: record of sensor {self.serial!r}, but the connected sensor is "
                f"{serial!r}: not resuming"
            )
        if not math.isclose(rate_hz, self.rate_hz):
            raise ChekanError(
                f"{path}: record at {self.rate_hz:g} Hz, sensor now reports {rate_hz:g} Hz"
            )


def _step_complete_in_record(rec: Record, step: int, n: int, rate: float) -> bool:
    """Whether the last uninterrupted run of ``step`` rows (consecutive rows, one sample
    period apart on the sample clock: no gap) holds ``n`` samples."""
    where = np.flatnonzero(rec.step == step)
    if where.size == 0:
        return False
    periods = np.round(np.diff(rec.t_s[where]) * rate)
    breaks = np.flatnonzero((np.diff(where) != 1) | (periods != 1))
    start = breaks[-1] + 1 if breaks.size else 0
    return where.size - start >= n


def resume_state(
    record_path: str | Path,
) -> tuple[ResumeState | None, dict[str, Any], list[PlanStep], dict[str, Any]]:
    """Read journal + record: ``(state or None if complete, run_start event, plan, last sync)``."""
    path = Path(record_path)
    jp = journal_path(path)
    if not jp.exists():
        raise ChekanError(f"{jp}: no journal: nothing to resume (start a new run instead)")
    events = read_journal(jp)
    start = next((e for e in events if e["event"] == Event.RUN_START), None)
    if start is None:
        raise ChekanError(f"{jp}: the run never started recording: start a new run instead")
    plan = [PlanStep.from_json(d) for d in start["plan"]]
    rate = float(start["rate_hz"])
    done = {int(e["step"]) for e in events if e["event"] == Event.STEP_DONE}
    stops = [e for e in events if e["event"] == Event.RUN_STOP]
    if stops and stops[-1].get("status") == "completed" and len(done) >= len(plan):
        return None, start, plan, {}  # complete and levelled: nothing to do
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = read_record(path)
    first = next((st for st in plan if st.index not in done), None)
    if first is not None and _step_complete_in_record(  # rows complete, step_done not journaled
        rec, first.index, first.dwell_samples(rate), rate
    ):
        done.add(first.index)
    pending = [st.index for st in plan if st.index not in done]
    syncs = [e for e in events if e["event"] == Event.SYNC]
    last_idx = last_seq = None
    if rec.n and syncs:
        ref = syncs[-1]
        last_idx = round(float(rec.t_s[-1]) * rate)
        ref_idx = round(float(ref["t_ref"]) * rate)
        last_seq = (int(ref["seq_ref"]) + last_idx - ref_idx) % SEQ_MOD
    elif rec.n:
        last_idx = round(float(rec.t_s[-1]) * rate)
    state = ResumeState(  # all steps done but never stopped cleanly: it only levels
        first_step=pending[0] if pending else len(plan),
        done=done,
        last_idx=last_idx,
        last_seq=last_seq,
        rate_hz=rate,
        serial=str(start["sensor"]["serial"]),
    )
    return state, start, plan, syncs[-1] if syncs else {}
