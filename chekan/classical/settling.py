"""What the sensor's lag leaves in the hold means, and the classical items without it.

The classical method (Calibr.exe, eqs. 21–25) takes a hold's mean reading after the
settling time as the equilibrium reading at the hold's angle. The CCD reading follows the
equilibrium with a first-order lag τ, so a hold whose settling time is short beside τ (the
designer's 120 s holds against τ ≈ 30–90 s) still carries part of the slew's transient,
and the items а)–в), the classical b and the verdict's reduced error carry it too. A joint
result fits τ; from it the transient in every hold mean is known and removed
(:func:`chekan.results.document.settled_items`), so that the certificate's items describe the
instrument, not the program. The classical method keeps Calibr.exe's items and says how far
they are moved (:func:`unsettled_hold_means`, with τ read off the record,
:func:`tau_from_transients`);
the designer states it for a program before it runs
(:func:`chekan.design.information.settled_transient_pix`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from chekan.physics.units import ARCMIN_PER_RAD, ARCSEC_PER_RAD

#: A transient above this in some hold mean (pix; ≈ 0.07 mGal, 3 % of the verdict's 0.05 %
#: of the 5 Gal range) makes the hold means unsettled: the joint result's classical items
#: are then computed from the hold means with the transient removed. Below it they are
#: Calibr.exe's, unchanged.
UNSETTLED_PIX = 0.01

#: τ (s) where no record tells it (legacy protocols have no samples): the prior's median
TAU_START_S = 30.0
#: τ (s) searched by :func:`tau_from_transients`: a coarse grid (neighbours 58 % apart), then
#: a fine one across the best coarse point's neighbours (8 % apart), then a parabola
TAU_COARSE_S = np.geomspace(1.0, 1000.0, 16)
_FINE_POINTS = 13
#: seconds of each hold, from its start, that the transient fit uses
TRANSIENT_WINDOW_S = 600.0
_MIN_SAMPLES = 8


@dataclass(frozen=True)
class JointValues:
    """What a joint fit's settled items rest on (:func:`settle`): its quadratic coefficient
    ``a`` (mGal/pix², record convention), the means of b₁, b₂, ε₁, ε₂, Δγ (arcmin) and τ (s)
    by name (a missing one reads 0), the level readings {"m1", "m2"} (pix), g (mGal), the
    CCD centre m₀ (pix) and whether the fit converged."""

    a: float | None
    means: Mapping[str, float]
    m_level_pix: Mapping[str, float]
    g_local_mgal: float
    ccd_center_pix: float
    converged: bool

    @classmethod
    def of_result(cls, result: Mapping[str, Any]) -> JointValues:
        """The values a ``chekan-result/1`` dict states (``a`` fixed: ``fixed.a``)."""
        p = result["parameters"]
        return cls(
            a=p["a"]["mean"] if "a" in p else (result.get("fixed") or {}).get("a"),
            means={n: e.get("mean", 0.0) for n, e in p.items()},
            m_level_pix=result.get("level_reading_pix") or {},
            g_local_mgal=result["g_local_mgal"],
            ccd_center_pix=result.get("ccd_center_pix", 1024.0),
            converged=bool((result.get("diagnostics") or {}).get("converged")),
        )

    @property
    def tau_s(self) -> float | None:
        """The lag τ (s), or None (a classical result has none)."""
        tau = self.means.get("tau_s")
        return float(tau) if isinstance(tau, int | float) and tau > 0 else None

    def model(self):  # -> chekan.physics.sensor.SensorParams | None
        """The forward model (chekan.physics.sensor: eqs. 6, 10 with ε₁, ε₂, Δγ) for the readings at
        any attitude; None where a ≤ 0 (a = g/(2K²) > 0 for a real pendulum)."""
        from chekan.physics import sensor as model

        a = self.a
        if not (isinstance(a, int | float) and a > 0):
            return None
        g = float(self.g_local_mgal)
        lv = self.m_level_pix

        def mean(name: str) -> float:
            return float(self.means.get(name, 0.0))

        return model.make_params(
            g_mgal=g,
            K_pix_per_rad=float(model.K_from_a(float(a), g)),
            b_mgal_per_pix=[mean("b1"), mean("b2")],
            m_level_pix=[float(lv["m1"]), float(lv["m2"])],
            eps_rad=[mean("eps1_arcmin") / ARCMIN_PER_RAD, mean("eps2_arcmin") / ARCMIN_PER_RAD],
            gamma_rad=mean("dgamma_arcmin") / ARCMIN_PER_RAD,
            m0_pix=float(self.ccd_center_pix),
        )


def fitted_model(result: Mapping[str, Any]):  # -> chekan.physics.sensor.SensorParams | None
    """The result's forward model (:meth:`JointValues.model`); None where a ≤ 0."""
    return JointValues.of_result(result).model()


def model_at_holds(params, holds: Any) -> np.ndarray:
    """The model's readings (n, 2) at the attitude measured in each hold (both axes)."""
    from chekan.physics import sensor as model

    tx = np.asarray(holds.tilt_x_rad, dtype=float)
    ty = np.asarray(holds.tilt_y_rad, dtype=float)
    return model.equilibrium_readings_host(params, tx, ty)


def _sample_attitudes(record: Any) -> tuple[np.ndarray, np.ndarray]:
    """(tx, ty) rad of every sample; a sample without angles takes the last finite ones."""
    tx = np.asarray(record.tilt_x_arcsec, dtype=float) / ARCSEC_PER_RAD
    ty = np.asarray(record.tilt_y_arcsec, dtype=float) / ARCSEC_PER_RAD
    ok = np.isfinite(tx) & np.isfinite(ty)
    first = int(np.argmax(ok))
    idx = np.maximum.accumulate(np.where(ok, np.arange(tx.size), first))
    return tx[idx], ty[idx]


def lagged_hold_means(params, holds: Any, record: Any, tau_s: float) -> np.ndarray:
    """The model's mean reading (n, 2) over the settled samples of each hold with the
    sensor's first-order lag followed through the record: yᵢ = ρyᵢ₋₁ + (1 − ρ)E(θᵢ),
    ρ = e^{−Δt/τ}, Eᵢ the equilibrium at the attitude recorded with sample i (each held
    over the sample before it, as the joint model holds it). A hold whose settling time is
    short beside τ still carries part of the slew's transient; E at the hold alone misses it."""
    from chekan.physics import sensor as model

    E = model.equilibrium_readings_host(params, *_sample_attitudes(record))
    rho = math.exp(-1.0 / (float(record.sample_rate_hz) * tau_s))
    y = model.lag_uniform(E - E[0], rho) + E[0]
    t = np.asarray(record.t_s, dtype=float)
    out = np.full((holds.n, 2), np.nan)
    for k in range(holds.n):
        a, b = int(holds.start[k]), int(holds.stop[k])
        sel = holds.settled(k, t)
        if sel.any():
            out[k] = y[a:b][sel].mean(axis=0)
    return out


def result_tau_s(result: Mapping[str, Any]) -> float | None:
    """The result's lag τ (s), or None (a classical result has none)."""
    return JointValues.of_result(result).tau_s


def unsettled_transient_pix(result: Mapping[str, Any], holds: Any, record: Any):
    """What the sensor's lag leaves in each hold's settled mean (n, 2), pix
    (:func:`transient_pix` of the result's values). None for a result without a model or
    without τ (classical)."""
    return transient_pix(JointValues.of_result(result), holds, record)


def transient_pix(values: JointValues, holds: Any, record: Any):
    """What the sensor's lag leaves in each hold's settled mean (n, 2), pix: the model's
    mean over the hold with the lag followed (:func:`lagged_hold_means`) minus its
    equilibrium there. None for values without a model or without τ."""
    params = values.model()
    tau = values.tau_s
    if params is None or record is None or tau is None:
        return None
    out = lagged_hold_means(params, holds, record, tau) - model_at_holds(params, holds)
    for k in range(
        holds.n
    ):  # after a gap the model takes the state as settled (chekan.records.holds)
        if holds.restarted(k):
            out[k] = 0.0
    return out


def transient_bound_pix(holds: Any, record: Any, tau_s: float) -> float:
    """An upper bound on :func:`unsettled_transient_pix` from the readings alone, without
    the model (cheap: it decides whether the model's transient is worth computing).

    While the platform holds still, the reading relaxes as m(t) = c + A e^{−t/τ} (t from
    the hold's start); its mean over the settled part [s, D] is m̄ = c + T, T = A τ (e^{−s/τ}
    − e^{−D/τ})/(D − s), |T| ≤ |A| e^{−s/τ}. So |A| ≤ (|m(t) − m̄| + 1 pix for noise and
    hold offsets) e^{t/τ}/(1 − e^{(t−s)/τ}) for any reading in the hold's first min(τ, s/2).
    A hold with no reading there gives ∞ (no bound)."""
    t = np.asarray(record.t_s, dtype=float)
    m = np.stack([record.m1_pix, record.m2_pix], axis=1).astype(float)
    s = float(holds.settle_s)
    worst = 0.0
    for k in range(holds.n):
        a, b = int(holds.start[k]), int(holds.stop[k])
        tt = t[a:b] - t[a]
        d = float(tt[-1]) if tt.size else 0.0
        if d <= s or holds.restarted(k):  # after a gap: taken as settled (chekan.records.holds)
            continue
        early = tt <= min(tau_s, s / 2.0)
        grow = (np.exp(tt[early] / tau_s) / (1.0 - np.exp((tt[early] - s) / tau_s)))[:, None]
        dev = (np.abs(m[a:b][early] - np.asarray(holds.m_mean_pix[k], dtype=float)) + 1.0) * grow
        if not np.isfinite(dev).any():
            return math.inf
        amp = float(np.nanmax(dev))
        worst = max(worst, amp * tau_s * (math.exp(-s / tau_s) - math.exp(-d / tau_s)) / (d - s))
    return worst


@dataclass(frozen=True)
class Settling:
    """What :func:`settle` found for a joint fit: whether it ``converged``; if not, the
    classical fit's ``unsettled`` flag (:func:`unsettled_hold_means`, or None); if so, the
    largest transient left in a hold mean (``transient_max_pix``, pix; None: the hold means
    are settled), τ and the settling time (s), and the classical fit of the hold means
    less the transient (``refit``; None where it failed), with the record's prior b and
    CCD range that its items are stated against."""

    converged: bool
    unsettled: Unsettled | None = None
    transient_max_pix: float | None = None
    tau_s: float | None = None
    settle_s: float | None = None
    refit: Any = None  # chekan.classical.fit.ClassicalResult | None
    b_prior: Any = None
    ccd_range_pix: Any = None


def settle(
    values: JointValues,
    holds: Any,
    record: Any,
    *,
    classical: Any = None,
    a_fixed: float | None = None,
) -> Settling:
    """Whether the lag leaves more than :data:`UNSETTLED_PIX` in some hold mean of a joint fit
    (:func:`transient_pix`) and, where it does, the classical method (eqs. 21–25, as
    Calibr.exe) on the hold means less that transient (:class:`Settling`). A fit that did
    not converge has no transient to trust: the ``classical`` fit's
    :func:`unsettled_hold_means` is given where it applies."""
    if not values.converged:
        unsettled = None
        if classical is not None:
            unsettled = unsettled_hold_means(holds, record, classical, a_fixed=a_fixed)
        return Settling(converged=False, unsettled=unsettled)
    tau = values.tau_s
    transient = None
    if tau is not None and transient_bound_pix(holds, record, tau) > UNSETTLED_PIX:
        transient = transient_pix(values, holds, record)
    if transient is None or not np.nanmax(np.abs(transient)) > UNSETTLED_PIX:
        return Settling(converged=True)  # the hold means settled
    cres = _refit(holds, record, np.asarray(holds.m_mean_pix) - transient, a_fixed=a_fixed)
    return Settling(
        converged=True,
        transient_max_pix=float(np.nanmax(np.abs(transient))),
        tau_s=tau,
        settle_s=float(holds.settle_s),
        refit=cres,
        b_prior=record.b_prior,
        ccd_range_pix=record.ccd_range_pix,
    )


def _refit(holds: Any, record: Any, means: np.ndarray, *, a_fixed: float | None, preview=False):
    """The classical fit (eqs. 21–25, :func:`chekan.classical.fit.fit_by_axis`) of ``holds`` with
    their hold means replaced by ``means``; None where it fails (the fit of the raw means of
    the same holds passed, so a failure is not expected: it must not lose a calibration)."""
    from chekan.classical.fit import fit_by_axis, increments_from_holds
    from chekan.errors import ChekanError

    settled = dataclasses.replace(holds, m_mean_pix=means)
    try:
        table = increments_from_holds(settled, record.g_local_mgal)
        return fit_by_axis(table, a_fixed=a_fixed, preview=preview)
    except (ChekanError, ValueError, np.linalg.LinAlgError):
        return None


def tau_from_transients(record, holds) -> float:
    """The lag τ (s) that best fits first-order settling in every hold, or ``TAU_START_S``.

    A hold starts where its slew ends; from then on the platform is still and the reading
    relaxes to its equilibrium, m(t) = cₖⱼ + Aₖⱼ e^{−t/τ} (t from the hold's start; the lag
    of the model's reading, the same in both systems). For each τ, cₖⱼ and Aₖⱼ are linear and
    projected out (least squares per hold k and system j over the first
    ``TRANSIENT_WINDOW_S`` of each hold), and the summed residual sum of squares S(τ) is
    minimised: on ``TAU_COARSE_S``, then on a fine grid between the best point's neighbours,
    then by a parabola in log τ. Holds with large transients weigh most. This is a start,
    not an estimate: drift and noise are ignored, and the MAP estimates τ with the full
    model. Host NumPy, ≈ 5 ms for a one-round session and 25–35 ms for a 3 h or 9 h record.
    """
    t = np.asarray(record.t_s, dtype=float)
    m = np.stack([record.m1_pix, record.m2_pix], axis=1).astype(float)
    pieces = []  # (t from the hold's start, centred reading) per hold and system
    for a, b in zip(holds.start, holds.stop, strict=True):
        tt = t[a:b] - t[a]
        inside = (tt <= TRANSIENT_WINDOW_S) & np.isfinite(tt)
        for j in range(2):
            ok = inside & np.isfinite(m[a:b, j])
            if ok.sum() >= _MIN_SAMPLES:
                y = m[a:b, j][ok]
                pieces.append((tt[ok], y - y.mean()))
    if not pieces:
        return TAU_START_S

    def ssr(grid: np.ndarray) -> np.ndarray:
        """S(τ) on ``grid``: the residual sum of squares left by c + A e^{−t/τ}."""
        out = np.zeros(grid.size)
        for tt, yc in pieces:
            e = np.exp(-tt[None, :] / grid[:, None])  # (G, n)
            e -= e.mean(axis=1, keepdims=True)
            num = e @ yc
            den = np.einsum("gn,gn->g", e, e)
            out += yc @ yc - np.divide(num * num, den, out=np.zeros_like(num), where=den > 1e-300)
        return out

    coarse = ssr(TAU_COARSE_S)
    if not np.all(np.isfinite(coarse)):
        return TAU_START_S
    k = int(np.argmin(coarse))
    lo, hi = TAU_COARSE_S[max(k - 1, 0)], TAU_COARSE_S[min(k + 1, TAU_COARSE_S.size - 1)]
    grid = np.geomspace(lo, hi, _FINE_POINTS)
    s = ssr(grid)
    k = int(np.argmin(s))
    if 0 < k < grid.size - 1:  # vertex of the parabola through three neighbours, in log τ
        curv = s[k - 1] - 2 * s[k] + s[k + 1]
        if curv > 0:
            step = math.log(grid[k + 1] / grid[k])
            return float(grid[k] * math.exp(0.5 * step * (s[k - 1] - s[k + 1]) / curv))
    return float(grid[k])


def raw_transient_pix(holds: Any, record: Any, tau_s: float) -> np.ndarray:
    """What the lag leaves in each hold's settled mean (n, 2), pix, from the readings alone
    (no model: the classical method's check). Per hold and system, least squares of
    m(t) = c + A e^{−t/τ} over the whole hold (t from its start, where the slew ends), then
    A times the mean of e^{−t/τ} over the settled samples. NaN where a hold has too few
    readings."""
    t = np.asarray(record.t_s, dtype=float)
    m = np.stack([record.m1_pix, record.m2_pix], axis=1).astype(float)
    out = np.full((holds.n, 2), np.nan)
    for k in range(holds.n):
        a, b = int(holds.start[k]), int(holds.stop[k])
        tt = t[a:b] - t[a]
        e = np.exp(-tt / tau_s)
        settled = holds.settled(k, t)
        for j in range(2):
            ok = np.isfinite(m[a:b, j])
            if ok.sum() < _MIN_SAMPLES or not (settled & ok).any():
                continue
            X = np.stack([np.ones(int(ok.sum())), e[ok]], axis=1)
            (_, amp), *_ = np.linalg.lstsq(X, m[a:b, j][ok], rcond=None)
            out[k, j] = amp * e[settled & ok].mean()
    return out


@dataclass(frozen=True)
class Unsettled:
    """Hold means that a classical fit takes as settled and are not
    (:func:`unsettled_hold_means`): the largest transient left in one (pix), the lag τ read
    off the record and the settling time (s); where the fit without the transient
    succeeded, its b₁, b₂ (``b_without``), the shift of the fit's b from them (% and sd;
    NaN where the fit has no sd yet)."""

    max_pix: float
    tau_s: float
    settle_s: float
    b_without: tuple[float, float] | None = None
    shift_percent: tuple[float, float] | None = None
    shift_sd: tuple[float, float] | None = None

    @property
    def problem(self) -> str:
        """The classical result's problem, one line."""
        head = (
            f"the hold means still carry up to {self.max_pix:.2g} pix of the slews' transients "
            f"(settling time {self.settle_s:g} s against the lag τ ≈ {self.tau_s:.0f} s read "
            "off the record), which the classical items take as settled"
        )
        tail = "--method map or bayes fits the lag and computes the items from settled hold means"
        if self.b_without is None or self.shift_percent is None or self.shift_sd is None:
            return f"{head}; {tail}"
        would = ", ".join(
            f"b{j + 1} {self.shift_percent[j]:+.3f} % ("
            + (f"{self.shift_sd[j]:.1f} sd; " if math.isfinite(self.shift_sd[j]) else "")
            + f"{self.b_without[j]:.6f} without)"
            for j in range(2)
        )
        return f"{head}: {would}; {tail}"

    def entry(self) -> dict:
        """The result's ``unsettled_hold_means``."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def unsettled_hold_means(
    holds: Any, record: Any, fit: Any, *, a_fixed: float | None = None, preview: bool = False
) -> Unsettled | None:
    """Whether the classical ``fit`` (:class:`chekan.classical.fit.ClassicalResult` of ``holds``)
    takes unsettled hold means as settled enough to matter; None otherwise.

    The lag τ is read off the record (:func:`tau_from_transients`) and the transient left in
    each hold mean from the readings (:func:`raw_transient_pix`); where it exceeds
    :data:`UNSETTLED_PIX`, the classical method runs again on the hold means less it. It
    matters when b₁ or b₂ moves by more than a third of its sd (an uncorrected bias of sd/3
    enlarges the uncertainty by 5 %), or when that fit fails."""
    tau = tau_from_transients(record, holds)
    transient = raw_transient_pix(holds, record, tau)
    worst = float(np.nanmax(np.abs(transient), initial=0.0))
    if not worst > UNSETTLED_PIX:
        return None
    found = Unsettled(max_pix=worst, tau_s=float(tau), settle_s=float(holds.settle_s))
    settled_means = np.asarray(holds.m_mean_pix) - np.nan_to_num(transient)
    again = _refit(holds, record, settled_means, a_fixed=a_fixed, preview=preview)
    if again is None:
        return found
    b = np.asarray(again.b_mean, dtype=float)
    shift = np.asarray(fit.b_mean, dtype=float) - b
    sd = np.asarray(fit.b_mean_sd, dtype=float)
    known = np.isfinite(sd) & (sd > 0)  # a preview of one pair has no sd yet
    in_sd = np.where(known, np.abs(shift) / np.where(known, sd, 1.0), np.nan)
    if known.any() and not np.nanmax(in_sd) > 1.0 / 3.0:
        return None
    return dataclasses.replace(
        found,
        b_without=(float(b[0]), float(b[1])),
        shift_percent=(float(100 * shift[0] / b[0]), float(100 * shift[1] / b[1])),
        shift_sd=(float(in_sd[0]), float(in_sd[1])),
    )
