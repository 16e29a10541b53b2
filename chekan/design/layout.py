"""Program layout for the design: holds, slews and bins as a record is binned, clock time,
and the damping lag's mixing of them (:func:`lagged_means`).

**Clock time.** The simulator's and the acquisition's timing: a slew of the platform at
0.5°/s plus 3 s of platform settling before every hold whose attitude changes, then
``dwell_s`` of samples at 1 Hz. ``program_clock_s`` is that total; the search keeps it
within the budget (default: the given program's clock time).

"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from chekan.joint.angles import DEFAULT_BOUND_ARCSEC, AngleSensorSpec, spec_for
from chekan.joint.binning import BIN_EDGES_S
from chekan.physics.program import TiltProgram
from chekan.records.simulate import Truth

if TYPE_CHECKING:  # pragma: no cover
    from chekan.records.anglecal import AngleCalibration


@dataclass(frozen=True)
class DesignValues:
    """Design values of the instrument and of the estimator's error model.

    ``truth``: instrument, noise (``noise_pix`` per 1 Hz sample), hold offsets
    (``hold_offset_sd_pix``), angle readout (``angle_error_sd_arcsec``), damping lag
    (``tau_s``), slew speed and platform settling. The switches turn nuisances off (for
    analytic checks): ``hold_offsets``, ``angle_errors``, ``drift``, ``estimate_tau``;
    ``priors=False`` drops the priors of θ, c and d (flat).

    ``angle_bound_arcsec``: the platform angle sensors' specification bound U (the paper:
    3″, :data:`chekan.joint.angles.DEFAULT_BOUND_ARCSEC`), read as the systematic error
    per commanded angle and the scale error of each axis's sensor
    (:class:`chekan.joint.angles.AngleSensorSpec`: each with the full u² = U²/3 by default,
    or ``angle_scale_share`` of it to the scale and the rest to the per-angle part);
    0: no systematic error (the random δ only, as before). ``angle_calibration``: the
    platform's own angle calibration (:mod:`chekan.records.anglecal`); where it has a table of an
    axis, that sensor's terms take the table's u(θ) = U(θ)/2 instead of the bound, as the
    estimator does (:func:`chekan.joint.angles.spec_for`). ``horizontal_u_pix``: the
    standard uncertainty of each pendulum's horizontal about the CCD centre that the
    estimator assumes where a program tilts about X (None: the model's own assumption,
    :func:`chekan.joint.xresponse.horizontal_prior`).
    """

    truth: Truth = field(default_factory=Truth)
    slew_error: float = 0.003  # κ: chekan.joint.problem.default_hyper default
    drift_degree: int = 3
    bin_edges_s: tuple[float, ...] = BIN_EDGES_S
    hold_offsets: bool = True
    angle_errors: bool = True
    drift: bool = True
    estimate_tau: bool = True
    priors: bool = True
    angle_bound_arcsec: float = DEFAULT_BOUND_ARCSEC
    angle_scale_share: float | None = None
    angle_calibration: AngleCalibration | None = field(default=None, compare=False)
    horizontal_u_pix: float | None = None  # None: the model's own assumption

    @property
    def angle_spec(self) -> AngleSensorSpec:
        """The angle sensors' specification bound these values assume (both axes alike)."""
        return AngleSensorSpec(self.angle_bound_arcsec, self.angle_scale_share)

    def angle_spec_of(self, axis: str) -> AngleSensorSpec:
        """What is known of the ``axis`` sensor: its table in :attr:`angle_calibration`,
        else the bound (:attr:`angle_spec`)."""
        cal = self.angle_calibration
        if cal is not None and cal.table(axis) is not None:
            return spec_for({}, None, axis=axis, calibration=cal)
        return AngleSensorSpec(self.angle_bound_arcsec, self.angle_scale_share, axis=axis)

    @property
    def systematic(self) -> bool:
        """Whether the angle sensors' systematic terms are modelled (a bound above 0 or a
        calibration table)."""
        return self.angle_bound_arcsec > 0.0 or self.angle_calibration is not None

    def without_systematic(self) -> DesignValues:
        """These values with the random angle error only (the comparison the design prints)."""
        return replace(self, angle_bound_arcsec=0.0, angle_calibration=None)


# ----------------------------------------------------------------------------- layout


@dataclass(frozen=True)
class Layout:
    """A program laid out at the sample rate the way a record of it is binned.

    Holds k = 0…H−1 with their signed tilt about their own axis and that axis
    (``hold_axis``: "x" or "y", the angle sensor that reads it); slews (H, M) padded,
    ``slew_lag_s`` = t_last − t of each slew sample
    (t_last: the last sample before the hold); bins (N,) with their hold, the time from
    t_last to their first sample ``bin_d0_s`` (10⁹ for hold 0: settled from the start),
    sample count and mid time.
    """

    theta_hold_rad: np.ndarray
    hold_axis: np.ndarray
    n_hold: np.ndarray
    slew_theta_rad: np.ndarray
    slew_lag_s: np.ndarray
    slew_mask: np.ndarray
    bin_hold: np.ndarray
    bin_d0_s: np.ndarray
    bin_n: np.ndarray
    bin_t_mid_s: np.ndarray
    dt_s: float
    clock_s: float


def _slew_samples(prev_rad: float, cmd_rad: float, truth: Truth) -> np.ndarray:
    """Attitudes of the samples of one move, as :func:`chekan.records.simulate.program_timeline`
    lays them out: ⌈|Δθ|/v/Δt⌉ slew samples then ⌈settle/Δt⌉ at the target."""
    dt = 1.0 / truth.sample_rate_hz
    dist_deg = math.degrees(abs(cmd_rad - prev_rad))
    if dist_deg == 0.0:
        return np.zeros(0)
    n_slew = max(math.ceil(dist_deg / truth.slew_deg_per_s / dt), 1)
    n_move = n_slew + math.ceil(truth.platform_settle_s / dt)
    f = np.minimum(np.arange(1, n_move + 1) / n_slew, 1.0)
    return prev_rad + f * (cmd_rad - prev_rad)


def _bin_edges(settle_s: float, edges_s) -> list[float]:
    return sorted({e for e in edges_s if e < settle_s} | {settle_s})


def program_layout(program: TiltProgram, values: DesignValues | None = None) -> Layout:
    """Lay out holds, slews and bins exactly as a simulated record of ``program`` is binned
    by :func:`chekan.joint.binning.prepare_record` (settle time from the program)."""
    values = values or DesignValues()
    truth = values.truth
    dt = 1.0 / truth.sample_rate_hz
    steps = program.steps
    H = len(steps)
    theta = np.array([s.theta_rad for s in steps])
    axes = np.array([s.axis for s in steps])
    for k in range(1, H):  # a move between axes would be a two-axis slew: level to level only
        if axes[k] != axes[k - 1] and (theta[k] != 0.0 or theta[k - 1] != 0.0):
            raise ValueError(f"step {k}: the axis changes away from level")
    n_hold = np.array([round(s.dwell_s / dt) for s in steps], dtype=int)
    slews = [np.zeros(0)] + [_slew_samples(theta[k - 1], theta[k], truth) for k in range(1, H)]
    M = max(1, max(s.size for s in slews))
    sl_th, sl_lag = np.zeros((H, M)), np.zeros((H, M))
    sl_mask = np.zeros((H, M), bool)
    edges = _bin_edges(program.settle_s, values.bin_edges_s)
    b_hold, b_d0, b_n, b_tm = [], [], [], []
    t_next = 0.0  # time of the next sample
    for k in range(H):
        m = slews[k].size
        sl_th[k, :m] = slews[k]
        sl_lag[k, :m] = dt * np.arange(m - 1, -1, -1)
        sl_mask[k, :m] = True
        t_next += m * dt
        t_last = t_next - dt  # last sample before the hold
        n = int(n_hold[k])
        rel_last = (n - 1) * dt
        hold_edges = [e for e in edges if e <= rel_last] + [math.inf]
        for lo, hi in itertools.pairwise(hold_edges):
            i_lo = math.ceil(lo / dt - 1e-9)
            i_hi = n if math.isinf(hi) else min(math.ceil(hi / dt - 1e-9), n)
            if i_hi <= i_lo:
                continue
            b_hold.append(k)
            b_d0.append((i_lo + 1) * dt if k else 1e9)
            b_n.append(i_hi - i_lo)
            b_tm.append(t_last + dt * (0.5 * (i_lo + i_hi - 1) + 1))
        t_next += n * dt
    return Layout(
        theta_hold_rad=theta,
        hold_axis=axes,
        n_hold=n_hold,
        slew_theta_rad=sl_th,
        slew_lag_s=sl_lag,
        slew_mask=sl_mask,
        bin_hold=np.array(b_hold),
        bin_d0_s=np.array(b_d0),
        bin_n=np.array(b_n, dtype=float),
        bin_t_mid_s=np.array(b_tm),
        dt_s=dt,
        clock_s=t_next,
    )


def program_clock_s(program: TiltProgram, values: DesignValues | None = None) -> float:
    """Session clock time of a program: dwells plus slews (0.5°/s) and platform settling."""
    truth = (values or DesignValues()).truth
    dt = 1.0 / truth.sample_rate_hz
    th = [s.theta_rad for s in program.steps]
    moves = sum(_slew_samples(a, b, truth).size for a, b in itertools.pairwise(th))
    return dt * (moves + sum(round(s.dwell_s / dt) for s in program.steps))


# ----------------------------------------------------------------------------- lag operator


@dataclass(frozen=True)
class Lagged:
    """Bin-level mean readings f (N, 2, C) for C columns of E, the mixing matrix G as its
    two diagonals (own: 1 − w, prev: w·w_prev) and the transient amplitude (N, 2)."""

    f: np.ndarray
    g_own: np.ndarray
    g_prev: np.ndarray
    trans: np.ndarray


def lagged_means(layout: Layout, tau_s: float, E_hold: np.ndarray, E_slew: np.ndarray) -> Lagged:
    """Bin means of the lagged equilibrium (chekan.joint.hold_blocks.bin_design in NumPy).

    wₘ = (1 − e^{−Δt/τ}) e^{−lagₘ/τ} along the slew into hold k, w_prev = 1 − Σwₘ,
    M_v = Σ wₘ E(θₘ); lag state after the slew y₀,ₖ = w_prev (E_{k−1} + (y₀,ₖ₋₁ − E_{k−1})ρ_{k−1})
    + M_v,ₖ with ρ = e^{−n_k Δt/τ}; Rₖ = y₀,ₖ − w_prev,ₖ E_{k−1} − M_v,ₖ; and a bin with lag
    weight wᵢ = e^{−d₀/τ}(1 − e^{−nΔt/τ})/(n(1 − e^{−Δt/τ})) reads
    fᵢ = (1 − wᵢ) Eₖ + wᵢ w_prev,ₖ E_{k−1} + wᵢ (M_v,ₖ + Rₖ).
    ``E_hold`` (H, 2, C), ``E_slew`` (H, M, 2, C): f is linear in them.
    """
    dt = layout.dt_s
    wm = np.where(
        layout.slew_mask, -math.expm1(-dt / tau_s) * np.exp(-layout.slew_lag_s / tau_s), 0.0
    )
    wprev = 1.0 - wm.sum(axis=1)
    Mv = np.einsum("hm,hmjc->hjc", wm, E_slew)
    rho = np.exp(-layout.n_hold * dt / tau_s)
    H = E_hold.shape[0]
    R = np.zeros_like(E_hold)
    y0 = E_hold[0].copy()
    for i in range(1, H):
        base = wprev[i] * E_hold[i - 1] + Mv[i]
        R[i] = wprev[i] * rho[i - 1] * (y0 - E_hold[i - 1])
        y0 = base + R[i]
    k = layout.bin_hold
    n = layout.bin_n
    q = np.where(n > 1, -np.expm1(-n * dt / tau_s) / (n * -math.expm1(-dt / tau_s)), 1.0)
    w = np.exp(-layout.bin_d0_s / tau_s) * q
    kp = np.maximum(k - 1, 0)
    g_own = 1.0 - w
    g_prev = np.where(k > 0, w * wprev[k], 0.0)
    f = g_own[:, None, None] * E_hold[k] + g_prev[:, None, None] * E_hold[kp]
    f = f + w[:, None, None] * (Mv[k] + R[k])
    # the slew error's scale (chekan.joint.likelihood.transient_amplitude), values only
    E0, Es0 = E_hold[:, :, 0], E_slew[:, :, :, 0]
    E0_prev = np.concatenate([E0[:1], E0[:-1]])
    along = np.einsum("hm,hmj->hj", wm, np.abs(Es0 - E0[:, None, :]))
    amp = wprev[:, None] * np.abs(E0_prev - E0) + along + np.abs(R[:, :, 0])
    trans = w[:, None] * amp[k]
    return Lagged(f=f, g_own=g_own, g_prev=g_prev, trans=trans)
