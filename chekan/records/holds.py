"""From a record to holds: which samples belong to which platform attitude.

A *hold* is the last contiguous run of samples that carry one program ``step``
(a resumed step keeps its earlier partial run in the record, but only the complete
last run is a hold). Each hold is classified from the angle sensors, not from a
program file, so records of any program (or of another recorder) are understood:

- level if the tilt magnitude is below ``level_threshold_deg``;
- otherwise a tilt of signed angle θ about its own dominant axis (X or Y): a record may
  hold rounds about both axes (``hold_axis``; ``axis`` is "y", "x" or "xy");
- a *round* is a maximal run of tilt holds between level holds, with the level
  holds on either side as its level references; a round is about one axis (a round
  whose tilts change axis is split where the axis changes);
- tilt magnitudes are clustered (tolerance ``angle_tol_deg``) into the program's angles.

Dwell means use the samples after ``settle_s`` from the start of the hold.

**Gaps** (lost samples: consecutive ``t_s`` further apart than 1.5 sample periods) are
not slews. Where the record has no attitude for a slew (a gap between the last sample of
a hold and the first of the next, or a slew sample without angles), the sensor's state at
the start of the next hold is unknown; so it is after a gap longer than
``GAP_HOLDING_S`` inside a hold (the acquisition may have stopped and commanded the
platform again). Such a state is unknown until the sensor settles: the samples within
``settle_s`` of the gap's end are not used (:attr:`HoldTable.known`). A hold whose start
was unknown and that never settles leaves the next hold's start unknown too; one whose
slew was seen is followed through a gap inside it, and a hold after it starts from its
equilibrium. A shorter gap inside a hold, while the platform holds its step's target on
both sides, loses only its samples.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from chekan.errors import ChekanError
from chekan.physics.units import ARCSEC_PER_RAD, format_dms

GAP_PERIODS = 1.5  # consecutive samples further apart than this many periods: a gap
GAP_HOLDING_S = 5.0  # a gap inside a hold up to this long loses only its samples


@dataclass
class Round:
    number: int  # 1-based
    tilt_holds: list[int]  # indices into the hold table
    level_before: int | None
    level_after: int | None
    axis: str = "y"  # "x" or "y": the axis (and angle sensor) of the round's tilts


@dataclass
class HoldTable:
    """Per-hold summary of a record (arrays of length n_holds, ordered by step)."""

    step: np.ndarray
    is_level: np.ndarray
    round: np.ndarray  # 1-based for tilt holds, 0 for level holds
    angle_index: np.ndarray  # cluster index for tilt holds, -1 for level
    sign: np.ndarray  # +1 / −1 for tilts, 0 for level
    start: np.ndarray  # first sample index of the hold in the record
    stop: np.ndarray  # one past the last sample index
    t_start_s: np.ndarray
    t_end_s: np.ndarray
    t_mid_s: np.ndarray  # middle of the settled part
    n_used: np.ndarray
    m_mean_pix: np.ndarray  # (n, 2) dwell means after settling
    m_sd_pix: np.ndarray  # (n, 2) sample sd after settling
    tilt_x_rad: np.ndarray  # settled mean of the angle sensors
    tilt_y_rad: np.ndarray
    theta_rad: np.ndarray  # signed angle about the hold's own axis
    axis: str  # "y", "x", or "xy" when the record holds rounds about both
    angle_deg: np.ndarray  # (n_angles,) cluster magnitudes, ascending
    rounds: list[Round]
    settle_s: float
    warnings: list[str] = field(default_factory=list)
    hold_axis: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype="<U1"))
    """(n,) "x" or "y" per hold: the axis of a tilt; a level hold takes the axis of the
    round after it (of the last round for a trailing level hold)."""
    known: np.ndarray | None = None
    """(record rows,) False where the sensor's state is unknown after a gap (module
    docstring); None: the record has no gap that hides the state."""
    fresh: np.ndarray | None = None
    """(n,) True for a hold whose start state a gap hid (:func:`known_state`); None: none."""
    gaps: list[tuple[float, float]] = field(default_factory=list)
    """Every gap of the record: (t of the last sample before, t of the first after), s."""

    def settled(self, k: int, t: np.ndarray) -> np.ndarray:
        """The settled samples of hold k (a mask over its rows): ``settle_s`` after its
        start and outside the unknown state after a gap. ``t``: the record's ``t_s``."""
        a, b = int(self.start[k]), int(self.stop[k])
        sel = t[a:b] - t[a] >= self.settle_s
        return sel if self.known is None else sel & self.known[a:b]

    def restarted(self, k: int) -> bool:
        """Whether a gap hid hold k's start state (its slew not observed): the joint model
        then takes it as settled where it uses it, and nothing of the slew carries on. A
        hold whose start was seen follows its slew through a gap inside it."""
        return self.fresh is not None and bool(self.fresh[k])

    @property
    def n(self) -> int:
        return int(self.step.size)

    @property
    def angle_labels(self) -> list[str]:
        """Each hold's angle as the protocol prints it (±d°mm′ss″)."""
        return [format_dms(a, sign="pm") for a in self.angle_deg]


def _runs(step: np.ndarray) -> list[tuple[int, int, int]]:
    """Contiguous runs (step, start, stop) of equal non-negative step values."""
    if step.size == 0:
        return []
    change = np.flatnonzero(np.diff(step) != 0) + 1
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [step.size]])
    return [
        (int(step[a]), int(a), int(b)) for a, b in zip(starts, stops, strict=True) if step[a] >= 0
    ]


def sample_period_s(t: np.ndarray, sample_rate_hz: float) -> float:
    """The record's sample period: the nominal one, or the typical spacing of its samples
    where that is longer (a record kept at a lower rate than its sensor's)."""
    d = np.diff(t)
    return max(1.0 / float(sample_rate_hz), float(np.median(d)) if d.size else 0.0)


def record_gaps(t: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """Row indices i with a gap between rows i and i + 1 (lost samples)."""
    return np.flatnonzero(np.diff(t) > GAP_PERIODS * sample_period_s(t, sample_rate_hz))


def gap_before(t: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """Per row, whether samples were lost just before it (:func:`record_gaps`)."""
    gap = np.zeros(t.size, bool)
    gap[record_gaps(t, sample_rate_hz) + 1] = True
    return gap


def known_state(
    t: np.ndarray,
    attitude_ok: np.ndarray,
    start: np.ndarray,
    stop: np.ndarray,
    settle_s: float,
    sample_rate_hz: float,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the sensor's state is known (module docstring): ``(known, fresh)``, per row
    whether it is (False within ``settle_s`` of a hold's start after a slew with a gap or
    without angles, or of the end of a gap longer than ``GAP_HOLDING_S`` inside a hold),
    and per hold whether its start is unknown (``fresh``: a slew not observed, or a hold
    before it that never settled after such a start). None where no gap hides the state.
    ``attitude_ok``: rows whose angles were both read."""
    gap = gap_before(t, sample_rate_hz)
    known = np.ones(t.size, bool)
    fresh = np.zeros(start.size, bool)
    end_known = True
    for k in range(start.size):
        a, b = int(start[k]), int(stop[k])
        lost_from: list[float] = []
        if k:
            slew = slice(int(stop[k - 1]), a)
            seen = not gap[int(stop[k - 1]) : a + 1].any() and attitude_ok[slew].all()
            fresh[k] = not end_known or not seen
            if fresh[k]:
                lost_from.append(float(t[a]))
        inside = np.flatnonzero(gap[a + 1 : b]) + a + 1
        lost_from += [float(t[i]) for i in inside if t[i] - t[i - 1] > GAP_HOLDING_S]
        for t0 in lost_from:
            known[a:b] &= ~((t[a:b] >= t0) & (t[a:b] < t0 + settle_s))
        # a hold whose start was seen follows its slew through a gap inside it (the platform
        # holds its step's target); one whose start is unknown must have settled by its end
        end_known = not fresh[k] or float(t[b - 1]) >= max(lost_from) + settle_s
    return None if known.all() else (known, fresh)


def _short_holds_note(short: list[tuple[int, float]], settle_s: float) -> str:
    """One note for every hold that ends before ``settle_s``: none of it is used."""
    steps = [s for s, _ in short]
    one = len(steps) == 1
    which = f"step {steps[0]}" if one else f"{len(steps)} holds (steps {_ranges(steps)})"
    longest = max(d for _, d in short)
    return (
        f"{which} {'lasts' if one else 'last at most'} {longest:.0f} s, not longer than the "
        f"settling time excluded from each hold ({settle_s:g} s): "
        f"{'it gives' if one else 'they give'} no reading"
    )


def _ranges(values: list[int]) -> str:
    """``0–3, 5, 7–9`` from sorted whole numbers."""
    parts: list[str] = []
    i = 0
    while i < len(values):
        j = i
        while j + 1 < len(values) and values[j + 1] == values[j] + 1:
            j += 1
        parts.append(str(values[i]) if i == j else f"{values[i]}–{values[j]}")
        i = j + 1
    return ", ".join(parts)


def settle_of(record, settle_s: float | None = None) -> float:
    """The settling time a calibration excludes from each hold: ``settle_s``, else the
    record's ``program_settle_s``, else 300 s."""
    return float(record.meta.get("program_settle_s", 300.0)) if settle_s is None else settle_s


def segment_record(
    record,
    settle_s: float = 300.0,
    level_threshold_deg: float = 0.1,
    angle_tol_deg: float = 0.05,
) -> HoldTable:
    """Find the holds of ``record`` (see the module docstring); raise if none are usable."""
    src = record.path or "<record>"
    runs = _runs(np.asarray(record.step))
    last: dict[int, tuple[int, int]] = {}
    for s, a, b in runs:
        last[s] = (a, b)  # later runs of the same step replace earlier (resumed) ones
    steps = sorted(last)
    if not steps:
        raise ChekanError(f"{src}: no holds (no sample carries a step index)")
    t = np.asarray(record.t_s, dtype=float)
    m = np.stack([record.m1_pix, record.m2_pix], axis=1).astype(float)
    tx = np.asarray(record.tilt_x_arcsec, dtype=float) / ARCSEC_PER_RAD
    ty = np.asarray(record.tilt_y_arcsec, dtype=float) / ARCSEC_PER_RAD
    n = len(steps)
    out = {k: np.zeros(n) for k in ("t0", "t1", "tm", "nu", "tx", "ty")}
    start = np.zeros(n, dtype=np.int64)
    stop = np.zeros(n, dtype=np.int64)
    mm = np.full((n, 2), np.nan)
    msd = np.full((n, 2), np.nan)
    notes: list[str] = []
    short: list[tuple[int, float]] = []  # (step, length in s) of holds with no settled part
    unsettled: list[int] = []  # steps with no settled sample after a gap
    for i, s in enumerate(steps):
        start[i], stop[i] = last[s]
    rate = float(record.sample_rate_hz)
    state = known_state(t, np.isfinite(tx) & np.isfinite(ty), start, stop, settle_s, rate)
    known, fresh = state if state is not None else (None, None)
    gaps = [(float(t[i]), float(t[i + 1])) for i in record_gaps(t, rate)]
    for i, s in enumerate(steps):
        a, b = int(start[i]), int(stop[i])
        tt = t[a:b]
        sel = tt - tt[0] >= settle_s
        if known is not None and not known[a:b].all():
            sel &= known[a:b]
            if not sel.any():
                unsettled.append(s)
        elif not sel.any():
            short.append((s, float(tt[-1] - tt[0])))
        out["t0"][i], out["t1"][i] = tt[0], tt[-1]
        out["tm"][i] = tt[sel].mean() if sel.any() else np.nan
        out["nu"][i] = sel.sum()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mm[i] = np.nanmean(m[a:b][sel], axis=0) if sel.any() else np.nan
            msd[i] = np.nanstd(m[a:b][sel], axis=0) if sel.sum() > 1 else np.nan
            txs, tys = tx[a:b], ty[a:b]
            use = sel if sel.any() else slice(None)
            out["tx"][i] = np.nanmean(txs[use])
            out["ty"][i] = np.nanmean(tys[use])
    if short:
        notes.append(_short_holds_note(short, settle_s))
    if unsettled:
        notes.append(
            f"step{'s' if len(unsettled) > 1 else ''} {_ranges(unsettled)}: no settled sample"
            " after a gap in the record (the sensor's state is unknown until it settles): not used"
        )
    mag = np.sqrt(out["tx"] ** 2 + out["ty"] ** 2)
    is_level = mag < np.deg2rad(level_threshold_deg)
    tilts = ~is_level
    about_x = np.abs(out["tx"]) > np.abs(out["ty"])
    theta = np.where(is_level, 0.0, np.where(about_x, out["tx"], out["ty"]))
    sign = np.where(is_level, 0, np.sign(theta)).astype(np.int64)
    # cluster the magnitudes
    angle_index = np.full(n, -1, dtype=np.int64)
    mags = np.rad2deg(np.abs(theta[tilts]))
    centres: list[float] = []
    if mags.size:
        order = np.sort(mags)
        groups = np.split(order, np.flatnonzero(np.diff(order) > angle_tol_deg) + 1)
        centres = [float(g.mean()) for g in groups]
        for i in np.flatnonzero(tilts).tolist():
            angle_index[i] = int(np.argmin(np.abs(np.asarray(centres) - np.rad2deg(abs(theta[i])))))
    # rounds: maximal runs of tilt holds between level holds
    rounds: list[Round] = []
    rnd = np.zeros(n, dtype=np.int64)
    i = 0
    while i < n:
        if is_level[i]:
            i += 1
            continue
        j = i
        while j < n and not is_level[j] and about_x[j] == about_x[i]:
            j += 1
        r = Round(
            len(rounds) + 1,
            list(range(i, j)),
            i - 1 if i > 0 and is_level[i - 1] else None,
            j if j < n and is_level[j] else None,
            "x" if about_x[i] else "y",
        )
        if r.level_before is None or r.level_after is None:
            notes.append(
                f"round {r.number}: no level step "
                f"{'before' if r.level_before is None else 'after'} it;"
                " drift between level steps cannot be removed"
            )
        rnd[i:j] = r.number
        rounds.append(r)
        i = j
    if not rounds:
        raise ChekanError(f"{src}: no tilt holds found (all {n} holds are level)")
    hold_axis = np.where(about_x, "x", "y")
    for i in np.flatnonzero(is_level).tolist():
        after = [r for r in rounds if r.tilt_holds[0] > i]
        hold_axis[i] = after[0].axis if after else rounds[-1].axis
    axes = {r.axis for r in rounds}
    axis = "xy" if len(axes) > 1 else axes.pop()
    if not is_level.any():
        raise ChekanError(f"{src}: no level hold found: the level reading m_h is undefined")
    if gaps:
        lost = sum(b - a for a, b in gaps) - len(gaps) * sample_period_s(t, rate)
        where = ", ".join(f"{a:.0f}–{b:.0f}" for a, b in gaps[:5]) + (
            ", …" if len(gaps) > 5 else ""
        )
        notes.append(
            f"{len(gaps)} gap(s) in the record, {lost:.0f} s without samples (t = {where} s);"
            " the sensor's state after a gap is unknown until it settles"
            + (
                f": {int((~known).sum())} samples after them are not used"
                if known is not None
                else ""
            )
        )
    for msg in notes:
        warnings.warn(f"{src}: {msg}", stacklevel=2)
    return HoldTable(
        step=np.asarray(steps, dtype=np.int64),
        is_level=is_level,
        round=rnd,
        angle_index=angle_index,
        sign=sign,
        start=start,
        stop=stop,
        t_start_s=out["t0"],
        t_end_s=out["t1"],
        t_mid_s=out["tm"],
        n_used=out["nu"].astype(np.int64),
        m_mean_pix=mm,
        m_sd_pix=msd,
        tilt_x_rad=out["tx"],
        tilt_y_rad=out["ty"],
        theta_rad=theta,
        axis=axis,
        angle_deg=np.asarray(centres),
        rounds=rounds,
        settle_s=float(settle_s),
        warnings=notes,
        hold_axis=hold_axis,
        known=known,
        fresh=fresh,
        gaps=gaps,
    )


def program_coverage(holds: HoldTable, meta: dict) -> dict | None:
    """What of the tilt program the record lacks, or None where it holds every step: the
    program's steps are ``program_steps`` of the header (written by chekan's acquisition and
    simulator), else those up to the last one recorded (a missing tail is then not seen).
    A step is missing where the record has no sample of it, or none settled."""
    recorded = {int(s) for s, n in zip(holds.step, holds.n_used, strict=True) if n > 0}
    present = {int(s) for s in holds.step}
    try:
        total = int(meta["program_steps"])
    except (KeyError, ValueError):
        total = None
    n = total if total is not None else max(present) + 1
    missing = sorted(set(range(n)) - recorded)
    if not missing:
        return None
    unsettled = sorted(present & set(missing))
    what = f"steps {_ranges(missing)} of 0–{n - 1}" + (
        f" (of them {_ranges(unsettled)} without a settled sample)" if unsettled else ""
    )
    of = "the program's" if total is not None else "the recorded program's first"
    problem = (
        f"the record holds {n - len(missing)} of {of} {n} steps: {what} are missing;"
        " the calibration rests on part of the program"
    )
    return {
        "program_steps": n,
        "program_steps_known": total is not None,
        "steps_used": n - len(missing),
        "missing_steps": missing,
        "problems": [problem],
    }


def gaps_entry(holds: HoldTable) -> dict:
    """The record's gaps as the result states them: how many, where (s on the sample
    clock: the samples either side), and how many samples the unknown state after them
    leaves unused."""
    return {
        "count": len(holds.gaps),
        "at_s": [[a, b] for a, b in holds.gaps],
        "unused_samples": 0 if holds.known is None else int((~holds.known).sum()),
    }
