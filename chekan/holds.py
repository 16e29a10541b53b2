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
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from chekan.errors import ChekanError
from chekan.units import ARCSEC_PER_RAD, format_dms


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

    @property
    def n(self) -> int:
        return int(self.step.size)

    def angle_labels(self) -> list[str]:
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
    for i, s in enumerate(steps):
        a, b = last[s]
        start[i], stop[i] = a, b
        tt = t[a:b]
        sel = tt - tt[0] >= settle_s
        if not sel.any():
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
    )
