"""The classical method of Calibr.exe (paper eqs. 16–25), reproduced exactly.

Per round and system: dwell means after settling, the level reading m_h (drift
between the level steps before and after the round removed by linear
interpolation in time), the pair mean m = (m₊ + m₋)/2 (eq. 25), and the least
squares of (eq. 21)

    Δg = b (m − m_h) + a (m − m_h)²,     Δg = −g (1 − cos θ)  (eq. 14)

in the record's convention (readings grow with gravity, so tilts give m < m_h and
Δg < 0), with ``a`` fixed or fitted (one ``a`` for all rounds and systems: it
depends only on the optics, eq. 10). Reported as in the paper's protocol:

- δg = Δg_ref − dg, the residual of each angle in the protocol's positive
  convention (dg = −(b x + a x²) is the measured increment);
- СКП: RMS of δg about its mean, per column (round × system), population form;
- the reduced error: max over angles of |mean of δg over all columns| / 5 Gal;
- the discrepancy between rounds: mean over systems of (max − min)/mean of b;
- the instability: deviation of b from the prior b;
- b₀ = b + 2a(m₀ − m_h) (eq. 24); the range margin to the CCD ends in both directions;
- ε from the asymmetry of ± tilts (eq. 17): ε_θ = −(m₊ − m₋)/(m₊ + m₋ − 2m_h)·|θ|/2.

Rounds about the platform X axis are processed as Calibr.exe processes any round (the ±
pair of eq. 25 cancels the terms linear in θ; eqs. 21–24) and fitted apart from the Y
rounds, with their own ``a``: a tilt about X turns the pendulums in their own plane, so
the effective stiffness of eq. (6) changes by g·θ and the pair mean is
Δg ≈ g(1 − cos θ)·(1 + (gθ/λ)²) — in the ideal geometry, with m_h at the CCD centre, a
quadratic term ≈ 5a instead of a (λ = bK, a = g/2K²), and more terms where m_h is off
centre. Eq. (14) is the response to tilts about Y only: the classical certificate uses the
Y rounds; the X rounds' fit is reported beside it (:attr:`ClassicalResult.by_axis`), and
a record of X rounds alone gives a flagged result (``problems``). Eq. (17) holds for Y
rounds only, so ε comes from them alone.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from chekan.errors import ChekanError
from chekan.physics.units import ARCMIN_PER_RAD, format_dms
from chekan.records.holds import HoldTable, segment_record, settle_of

if TYPE_CHECKING:
    from chekan.classical.settling import Unsettled
    from chekan.records.inputs import ReadyInput

FULL_RANGE_MGAL = 5000.0  # Δ₀ = 5 Gal, the upper limit of the measuring range


def _one_minus_uz(tx, ty):
    """1 − cos tx · cos ty without cancellation."""
    hx = 2 * np.sin(np.asarray(tx) / 2) ** 2
    hy = 2 * np.sin(np.asarray(ty) / 2) ** 2
    return hx + hy - hx * hy


@dataclass
class IncrementTable:
    """Reading differences and reference increments per round, system and angle.

    ``x_pix`` is m − m_h of the ± pair mean in the record's convention (negative for
    tilts); ``da_ref_mgal`` = g(1 − cos θ) is positive.
    """

    source: str  # "record" or "protocol"
    g_local_mgal: float
    angle_deg: np.ndarray  # (n,)
    angle_label: list[str]
    rounds: tuple[int, ...]
    da_ref_mgal: np.ndarray  # (R, n)
    x_pix: np.ndarray  # (R, 2, n), NaN where missing
    x_plus_pix: np.ndarray | None = None  # (R, 2, n)
    x_minus_pix: np.ndarray | None = None
    theta_pair_rad: np.ndarray | None = None  # (R, n) mean |θ| of the pair
    m_level_pix: np.ndarray | None = None  # (R, 2)
    a_fixed: float | None = None  # record convention
    b_printed: np.ndarray | None = None  # (R, 2), protocols only
    notes: list[str] = field(default_factory=list)
    round_axes: tuple[str, ...] = ()  # "y"/"x" per round; empty: all about Y

    @property
    def axes(self) -> tuple[str, ...]:
        """The axis of every round ("y" throughout when not recorded)."""
        return self.round_axes or ("y",) * len(self.rounds)

    def for_axis(self, axis: str) -> IncrementTable | None:
        """The rounds about ``axis`` alone, with the angles that have an increment in them;
        None when no round is about ``axis``."""
        keep = [i for i, a in enumerate(self.axes) if a == axis]
        if not keep:
            return None
        sub = self.x_pix[keep]
        cols = np.flatnonzero(np.isfinite(sub).any(axis=(0, 1)))

        def pick(arr):  # (R, …, n) → the kept rounds and angles
            return None if arr is None else arr[keep][..., cols]

        kept = [f"round {self.rounds[i]}," for i in keep]
        return IncrementTable(
            source=self.source,
            g_local_mgal=self.g_local_mgal,
            angle_deg=self.angle_deg[cols],
            angle_label=[self.angle_label[i] for i in cols],
            rounds=tuple(self.rounds[i] for i in keep),
            da_ref_mgal=pick(self.da_ref_mgal),
            x_pix=pick(self.x_pix),
            x_plus_pix=pick(self.x_plus_pix),
            x_minus_pix=pick(self.x_minus_pix),
            theta_pair_rad=pick(self.theta_pair_rad),
            m_level_pix=None if self.m_level_pix is None else self.m_level_pix[keep],
            a_fixed=self.a_fixed,
            b_printed=None if self.b_printed is None else self.b_printed[keep],
            notes=[n for n in self.notes if n.startswith(tuple(kept))],
            round_axes=(axis,) * len(keep),
        )


def increments_from_holds(table: HoldTable, g_local_mgal: float) -> IncrementTable:
    """Pair ± tilts of every angle in every round; level reading interpolated in time."""
    return increments_of_readings(table, g_local_mgal, table.m_mean_pix[None])[0]


def increments_of_readings(
    table: HoldTable, g_local_mgal: float, readings: np.ndarray
) -> list[IncrementTable]:
    """:func:`increments_from_holds` of the table with its hold means replaced by each of
    ``readings`` (D, K, 2) in turn (a replicated session per row), computed together: the
    pairs, levels and reference increments are the table's, the readings enter linearly."""
    m = np.asarray(readings, dtype=float)
    D, R, n = m.shape[0], len(table.rounds), table.angle_deg.size
    x = np.full((D, R, 2, n), np.nan)
    xp = np.full((D, R, 2, n), np.nan)
    xm = np.full((D, R, 2, n), np.nan)
    da = np.full((R, n), np.nan)
    th = np.full((R, n), np.nan)
    mh_round = np.full((D, R, 2), np.nan)
    notes: list[str] = []
    lvl_h = _one_minus_uz(table.tilt_x_rad, table.tilt_y_rad)
    for ri, rnd in enumerate(table.rounds):
        refs = [i for i in (rnd.level_before, rnd.level_after) if i is not None]
        t_ref = table.t_mid_s[refs]
        m_ref = m[:, refs]  # (D, 1 or 2, 2)
        h_ref = lvl_h[refs].mean()
        mh_round[:, ri] = m_ref.mean(axis=1)

        def m_level_at(t, t_ref=t_ref, m_ref=m_ref):
            if len(t_ref) == 1 or t_ref[1] == t_ref[0]:
                return m_ref.mean(axis=1)
            w = (t - t_ref[0]) / (t_ref[1] - t_ref[0])
            return m_ref[:, 0] + w * (m_ref[:, 1] - m_ref[:, 0])

        for ai in range(n):
            hp = [i for i in rnd.tilt_holds if table.angle_index[i] == ai and table.sign[i] > 0]
            hm = [i for i in rnd.tilt_holds if table.angle_index[i] == ai and table.sign[i] < 0]
            if not hp or not hm:
                if hp or hm:
                    notes.append(
                        f"round {rnd.number}, angle {format_dms(table.angle_deg[ai], sign='pm')}: "
                        f"no {'−' if hp else '+'} partner, angle left out"
                    )
                continue
            dp = np.mean([m[:, i] - m_level_at(table.t_mid_s[i]) for i in hp], axis=0)
            dm = np.mean([m[:, i] - m_level_at(table.t_mid_s[i]) for i in hm], axis=0)
            xp[:, ri, :, ai], xm[:, ri, :, ai] = dp, dm
            x[:, ri, :, ai] = 0.5 * (dp + dm)  # eq. (25)
            hh = np.mean([lvl_h[i] for i in hp]) / 2 + np.mean([lvl_h[i] for i in hm]) / 2
            da[ri, ai] = g_local_mgal * (hh - h_ref)
            th[ri, ai] = 0.5 * (
                np.mean(np.abs(table.theta_rad[hp])) + np.mean(np.abs(table.theta_rad[hm]))
            )
    return [
        IncrementTable(
            source="record",
            g_local_mgal=g_local_mgal,
            angle_deg=table.angle_deg,
            angle_label=table.angle_labels,
            rounds=tuple(r.number for r in table.rounds),
            da_ref_mgal=da.copy(),  # each table its own arrays (a fit may edit what it holds)
            x_pix=x[d],
            x_plus_pix=xp[d],
            x_minus_pix=xm[d],
            theta_pair_rad=th.copy(),
            m_level_pix=mh_round[d],
            notes=list(notes),
            round_axes=tuple(r.axis for r in table.rounds),
        )
        for d in range(D)
    ]


def increments_from_protocol(protocol) -> IncrementTable:
    """Recover m − m_h from a legacy protocol by inverting dg = b x + a x² per round.

    The protocol counts increments positive (gravity felt decreases) and quotes ``a``
    in that convention; this is the one place where they are mapped onto the record's
    convention: x_record = −x_protocol, a_record = −a_protocol.
    """
    a_p = float(protocol.a_mgal_per_pix2)
    b = np.asarray(protocol.b_mgal_per_pix, dtype=float)  # (R, S)
    dg = np.asarray(protocol.dg_mgal, dtype=float)  # (R, S, n)
    if dg.shape[1] != 2:
        raise ChekanError(
            f"{protocol.path}: the protocol must hold both systems (has {dg.shape[1]})"
        )
    bb = b[:, :, None]
    if a_p == 0.0:
        x_p = dg / bb
    else:
        x_p = 2.0 * dg / (bb + np.sqrt(bb * bb + 4.0 * a_p * dg))  # stable root of a x² + b x − dg
    R = dg.shape[0]
    g = protocol.g_local_or_fitted()
    return IncrementTable(
        source="protocol",
        g_local_mgal=float(g),
        angle_deg=np.asarray(protocol.angle_deg, dtype=float),
        angle_label=[format_dms(a, sign="pm") for a in protocol.angle_deg],
        rounds=tuple(int(r) for r in protocol.rounds),
        da_ref_mgal=np.broadcast_to(
            np.asarray(protocol.da_ref_mgal, dtype=float), (R, dg.shape[2])
        ).copy(),
        x_pix=-x_p,
        theta_pair_rad=np.broadcast_to(np.deg2rad(protocol.angle_deg), (R, dg.shape[2])).copy(),
        a_fixed=-a_p,
        b_printed=b,
    )


@dataclass
class ClassicalResult:
    table: IncrementTable
    b: np.ndarray  # (R, 2)
    b_sd: np.ndarray  # (R, 2)
    a: float
    a_sd: float | None  # None when a was fixed
    dg_mgal: np.ndarray  # (R, 2, n) measured increments, positive convention
    delta_g_mgal: np.ndarray  # (R, 2, n) δg = Δg_ref − dg
    rms_mgal: np.ndarray  # (R, 2) СКП
    mean_delta_g_mgal: np.ndarray  # (n,)
    reduced_error_percent: float
    sigma_mgal: float  # pooled residual sd of the fit
    b_mean: np.ndarray  # (2,) over rounds
    b_mean_sd: np.ndarray
    mean_all: float  # the paper's «Среднее»
    discrepancy_percent: float | None
    eps_arcmin: np.ndarray | None  # (2,) eq. (17) mean over angles and rounds
    eps_sd_arcmin: np.ndarray | None
    notes: list[str] = field(default_factory=list)
    axis: str = "y"  # the axis of the rounds fitted: "y", "x" (or "xy": a mixed table)
    by_axis: dict[str, ClassicalResult] = field(default_factory=dict)
    """For a record with rounds about both axes: the fit of each axis's rounds ("y" is this
    result itself, the certificate's; "x" is reported beside it)."""
    problems: list[str] = field(default_factory=list)  # what makes the result doubtful

    @property
    def column_names(self) -> list[str]:
        return [f"r{r}_s{s}" for r in self.table.rounds for s in (1, 2)]

    def b0(self, m0_pix: float) -> np.ndarray | None:
        """(R, 2) b₀ = b + 2a(m₀ − m_h) (eq. 24); None without level readings."""
        if self.table.m_level_pix is None:
            return None
        return self.b + 2.0 * self.a * (m0_pix - self.table.m_level_pix)

    def instability_percent(self, b_prior) -> list[float | None]:
        """Deviation of the mean b of each system from the prior b, percent (signed)."""
        out: list[float | None] = []
        for s in range(2):
            p = b_prior[s] if b_prior is not None else None
            out.append(None if p is None else float((self.b_mean[s] - p) / p * 100.0))
        return out

    def range_margin_gal(self, ccd_range_pix: tuple[float, float]) -> dict[str, float] | None:
        """Gravity change to either end of the CCD from the level reading, the smaller of
        the two systems: ``heavy`` (gravity up, reading up) and ``light``."""
        if self.table.m_level_pix is None:
            return None
        mh = np.nanmean(self.table.m_level_pix, axis=0)
        lo, hi = ccd_range_pix
        up = self.b_mean * (hi - mh) + self.a * (hi - mh) ** 2
        down = -(self.b_mean * (lo - mh) + self.a * (lo - mh) ** 2)
        return {"heavy": float(np.min(up)) / 1000.0, "light": float(np.min(down)) / 1000.0}


def _check_degrees_of_freedom(X: np.ndarray, fits_a: bool) -> None:
    """Refuse a fit whose coefficients the data cannot determine with a residual left over:
    its uncertainty would be zero (or undefined), never an honest one."""
    n, p = X.shape
    if n <= p or np.linalg.matrix_rank(X) < p:
        what = "b of each round and system" + (", and a" if fits_a else "")
        raise ChekanError(
            f"too few angles for the classical method: {n} increments for {p} coefficients "
            f"({what}); at least one increment more than coefficients is needed (more "
            "angles" + (", or --a-fixed)" if fits_a else ")")
        )


def fit_classical(
    table: IncrementTable, a_fixed: float | None = None, *, preview: bool = False
) -> ClassicalResult:
    """Least squares of eq. (21) over all rounds and systems (see the module docstring).

    ``a_fixed`` (record convention) overrides the table's own fixed ``a``; with neither,
    one common ``a`` is fitted with the b of every round and system. Too few increments to
    leave a residual is an error, except for a ``preview`` (the live page's b after the first
    pairs, shown without an uncertainty to speak of).
    """
    a_fix = a_fixed if a_fixed is not None else table.a_fixed
    R, _, n = table.x_pix.shape
    y = -table.da_ref_mgal  # Δg, record convention
    cols = [(r, s) for r in range(R) for s in range(2)]
    rows_x, rows_y, rows_c = [], [], []
    for ci, (r, s) in enumerate(cols):
        ok = np.isfinite(table.x_pix[r, s]) & np.isfinite(y[r])
        rows_x.append(table.x_pix[r, s, ok])
        rows_y.append(y[r, ok])
        rows_c.append(np.full(ok.sum(), ci))
    xv, yv, cv = map(np.concatenate, (rows_x, rows_y, rows_c))
    if xv.size == 0:
        raise ChekanError("no complete ± pair in any round: nothing to fit")
    nb = len(cols)
    X = np.zeros((xv.size, nb + (a_fix is None)))
    X[np.arange(xv.size), cv] = xv
    if a_fix is None:
        X[:, nb] = xv**2
        target = yv
    else:
        target = yv - a_fix * xv**2
    present = np.flatnonzero(np.abs(X).sum(axis=0) > 0)
    if not preview:
        for s in range(2):
            if not any(np.any(cv == ci) for ci, (_, s_) in enumerate(cols) if s_ == s):
                raise ChekanError(
                    f"system {s + 1} has no complete ± pair in any round (no m{s + 1}_pix "
                    "readings in the holds): both quartz systems are calibrated together"
                )
        _check_degrees_of_freedom(X[:, present], fits_a=a_fix is None)
    coef = np.full(X.shape[1], np.nan)
    sol, *_ = np.linalg.lstsq(X[:, present], target, rcond=None)
    coef[present] = sol
    resid = target - X[:, present] @ sol
    dof = max(xv.size - present.size, 1)
    sigma = float(np.sqrt(resid @ resid / dof))
    cov = np.full((X.shape[1], X.shape[1]), np.nan)
    cov[np.ix_(present, present)] = sigma**2 * np.linalg.pinv(X[:, present].T @ X[:, present])
    b = coef[:nb].reshape(R, 2)
    b_sd = np.sqrt(np.diag(cov)[:nb]).reshape(R, 2)
    a = float(a_fix) if a_fix is not None else float(coef[nb])
    a_sd = None if a_fix is not None else float(np.sqrt(cov[nb, nb]))
    x = table.x_pix
    dg = -(b[:, :, None] * x + a * x**2)
    delta = table.da_ref_mgal[:, None, :] - dg
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean((delta - np.nanmean(delta, axis=2, keepdims=True)) ** 2, axis=2))
        mean_dg = np.nanmean(delta.reshape(R * 2, n), axis=0)
    reduced = float(np.nanmax(np.abs(mean_dg)) / FULL_RANGE_MGAL * 100.0)
    b_mean = np.nanmean(b, axis=0)
    b_mean_sd = np.sqrt(np.nansum(b_sd**2, axis=0)) / np.sum(np.isfinite(b), axis=0)
    disc = None
    if R >= 2:
        disc = float(np.mean((np.nanmax(b, axis=0) - np.nanmin(b, axis=0)) / b_mean) * 100.0)
    eps = eps_sd = None
    about_y = all(a == "y" for a in table.axes)  # eq. (17) is the asymmetry of tilts about Y
    if table.x_plus_pix is not None and table.theta_pair_rad is not None and about_y:
        with np.errstate(invalid="ignore", divide="ignore"):
            e = -(table.x_plus_pix - table.x_minus_pix) / (table.x_plus_pix + table.x_minus_pix)
            e = e * table.theta_pair_rad[:, None, :] / 2.0 * ARCMIN_PER_RAD  # eq. (17)
        e = np.moveaxis(e, 1, 0).reshape(2, -1)
        cnt = np.sum(np.isfinite(e), axis=1)
        eps = np.nanmean(e, axis=1)
        eps_sd = np.nanstd(e, axis=1, ddof=1) / np.sqrt(np.maximum(cnt, 1))
    return ClassicalResult(
        table=table,
        b=b,
        b_sd=b_sd,
        a=a,
        a_sd=a_sd,
        dg_mgal=dg,
        delta_g_mgal=delta,
        rms_mgal=rms,
        mean_delta_g_mgal=mean_dg,
        reduced_error_percent=reduced,
        sigma_mgal=sigma,
        b_mean=b_mean,
        b_mean_sd=b_mean_sd,
        mean_all=float(np.nanmean(b)),
        discrepancy_percent=disc,
        eps_arcmin=eps,
        eps_sd_arcmin=eps_sd,
        notes=list(table.notes),
        axis=_axes_word(table.axes),
    )


def _axes_word(axes) -> str:
    """ "y", "x", or "xy" for rounds about both axes."""
    present = set(axes) or {"y"}
    return "xy" if len(present) > 1 else present.pop()


def calibrate_record(record, settle_s: float | None = None, a_fixed: float | None = None):
    """Classical calibration of a record: ``(ClassicalResult, HoldTable)``
    (:func:`~chekan.records.holds.segment_record`, then :func:`fit_holds`); ``settle_s``
    None: the record's ``program_settle_s``, else 300 s."""
    holds = segment_record(record, settle_s=settle_of(record, settle_s))
    return fit_holds(holds, record, a_fixed), holds


def fit_holds(holds: HoldTable, record, a_fixed: float | None = None) -> ClassicalResult:
    """The classical fit of a record's holds (eqs. 16–25).

    Rounds about Y give the result (``a_fixed`` applies to them). A record that also holds
    rounds about X fits those apart, with their own ``a`` (:attr:`ClassicalResult.by_axis`;
    one that cannot be fitted is a note, not an error); a record of X rounds alone gives
    their fit, flagged in ``problems`` (eq. 14 is not the response to tilts about X).
    """
    if not np.any(holds.n_used > 0):
        longest = float(np.max(holds.t_end_s - holds.t_start_s))
        raise ChekanError(
            f"{record.path or '<input>'}: the settling time excluded from each hold "
            f"({holds.settle_s:g} s) is not shorter than any hold (the longest lasts "
            f"{longest:.0f} s): no reading is left to calibrate; give a smaller --settle-s"
        )
    table = increments_from_holds(holds, record.g_local_mgal)
    try:
        return fit_by_axis(table, a_fixed)
    except ChekanError as e:
        raise ChekanError(f"{record.path or '<input>'}: {e}") from None


def fit_by_axis(
    table: IncrementTable,
    a_fixed: float | None = None,
    *,
    preview: bool = False,
    x_apart: bool = True,
) -> ClassicalResult:
    """:func:`fit_classical` of a table whose rounds may be about both axes: the rounds
    about Y give the result (``a_fixed`` applies to them); the rounds about X are fitted
    apart with their own ``a`` (``by_axis["x"]``; one that cannot be fitted is a note;
    not fitted with ``x_apart=False``, for a caller that reads the result's own table
    only); X rounds alone give their fit, flagged in ``problems``. A table about Y alone:
    exactly :func:`fit_classical`."""
    if all(a == "y" for a in table.axes):
        return fit_classical(table, a_fixed=a_fixed, preview=preview)
    y_table, x_table = table.for_axis("y"), table.for_axis("x")
    assert x_table is not None
    if y_table is None:
        res = fit_classical(x_table, preview=preview)
        res.problems.append(X_ONLY_PROBLEM)
        return res
    res = fit_classical(y_table, a_fixed=a_fixed, preview=preview)
    if not x_apart:
        return res
    x_rounds = ", ".join(map(str, x_table.rounds))
    try:
        res.by_axis = {"y": res, "x": fit_classical(x_table, preview=preview)}
    except ChekanError as e:
        res.by_axis = {"y": res}
        res.notes.append(f"rounds about X ({x_rounds}) not fitted: {e}")
    res.notes.append(
        f"rounds about X ({x_rounds}) are fitted apart, with their own a, and reported beside "
        "the result; the classical b and a are those of the rounds about Y (eq. 14)"
    )
    return res


#: Why the classical fit of rounds about X alone is flagged.
X_ONLY_PROBLEM = (
    "every round is about the platform X axis: the classical Δg = g(1 − cos θ) (eq. 14) is "
    "the response to tilts about Y; about X the pendulums turn in their own plane (eq. 6), "
    "so b is biased and a is not the characteristic's a (about 5a)"
)


def calibrate_protocol(protocol, a_fixed: float | None = None) -> ClassicalResult:
    """Classical re-analysis of a legacy protocol table (``a`` fixed to the protocol's)."""
    return _fit_input(increments_from_protocol(protocol), a_fixed, protocol.path)


def _fit_input(table: IncrementTable, a_fixed: float | None, path: str | None) -> ClassicalResult:
    """:func:`fit_classical` of an input; what it cannot fit is an error naming the input."""
    try:
        return fit_classical(table, a_fixed=a_fixed)
    except ChekanError as e:
        raise ChekanError(f"{path or '<input>'}: {e}") from None


@dataclass(frozen=True)
class ClassicalFit:
    """The classical method on one input made ready (:func:`classical_fit`): the fit (its
    problems include the program's coverage and, where asked, the unsettled hold means)
    and a record's unsettled hold means (or None)."""

    result: ClassicalResult
    unsettled: Unsettled | None = None


def classical_fit(
    ready: ReadyInput, *, a_fixed: float | None = None, unsettled: bool = False
) -> ClassicalFit:
    """The classical method on an input made ready (:func:`chekan.records.inputs.ready_input`):
    :func:`fit_holds` of a record, :func:`calibrate_protocol` of a protocol; every method
    starts here (the classical fit seeds the MAP and is reported beside it).
    ``unsettled``: also look for hold means taken unsettled
    (:func:`chekan.classical.settling.unsettled_hold_means`; a joint result settles its
    items itself, :func:`chekan.classical.settling.settle`)."""
    from chekan.classical.settling import unsettled_hold_means

    data, holds, coverage = ready.data, ready.holds, ready.coverage
    if holds is None:
        return ClassicalFit(calibrate_protocol(data, a_fixed=a_fixed))
    cres = fit_holds(holds, data, a_fixed)
    if coverage is not None:
        cres = _flagged(cres, coverage["problems"])
    found = unsettled_hold_means(holds, data, cres, a_fixed=a_fixed) if unsettled else None
    if found is not None:
        cres = _flagged(cres, [found.problem])
    return ClassicalFit(cres, found)


def _flagged(cres: ClassicalResult, problems: list[str]) -> ClassicalResult:
    """``cres`` with ``problems`` added; its per-axis fits name the certificate's own by
    identity, so the copy stands for it there too."""
    flagged = dataclasses.replace(cres, problems=[*cres.problems, *problems])
    flagged.by_axis = {a: flagged if f is cres else f for a, f in cres.by_axis.items()}
    return flagged
