r"""Tilt-program design: the expected precision of b₁, b₂ and a from the Fisher information.

**What is computed.** For a tilt program and design values of the instrument (default:
:class:`chekan.simulate.Truth`, the simulator's instrument and error budget), the Laplace
covariance that the MAP estimator (:mod:`chekan.bayes`) would report, evaluated at the
design values with every random effect at its prior mean:

.. math::

    \Sigma = \Big(\sum_{j=1,2} X_jᵀ W_j X_j + Λ^{-1}\Big)^{-1},
    \qquad X_j = [\,∂f_j/∂θ,\ 1,\ P,\ G,\ G\,\mathrm{diag}(s_j)\,],

the inverse of the expected information of the joint record model of
:mod:`chekan.calmodel`, whose data are bin means inside every hold (bins 0–15–40–90–180 s
and ``settle_s`` across the settling transient, one bin after it):

.. math::

    ȳ_{ij} = f_{ij}(θ) + c_j + P(s_i)\,d_j + G_i\,(o_j + s_j ∘ δ) + e_{ij},\qquad
    e_{ij} \sim N\big(0,\ σ_j^2/n_i + (κ\,\mathrm{trans}_{ij})^2\big).

θ = (b₁, b₂, log K, ε₁, ε₂, Δγ, log τ) (the estimator's nonlinear parameters with their
priors from :func:`chekan.calmodel.nonlinear_params`); f = G E + w(M_v + R) is the lagged
exact torsion equilibrium (E at every hold, :func:`chekan.model.equilibrium_readings`,
first-order damping lag τ, the lag state after each slew filtered along the slew's
attitudes, the unsettled remainder R carried across holds); G is the (N × H) lag-mixing
matrix (1 − wᵢ on the bin's own hold, wᵢ w_prev on the previous one); c_j the level offset
(prior 1 pix²), d_j a Legendre drift of degree 3 without constant (prior 4 pix²), o_j the
per-hold offsets (prior σ_o² = 0.08²), δ the per-hold angle-readout errors **shared by both
systems** (prior σ_θ² = (2″)²) entering through s_j = −∂E_j/∂θ / 206265 (pix/″); n_i is the
bin's sample count, σ_j the 1 Hz noise (0.15 pix), κ the slew error (0.003) times the
transient still present in the bin. W_j = diag(1/var e_{·j}); Λ the prior covariance.

The Jacobian ∂f/∂θ is exact for the instrument parameters (f is linear in E, so
∂f/∂u = f evaluated on ∂E/∂u, from JAX forward-mode on a fixed grid of attitudes and a
cubic spline, error < 1e-10 pix) and a central difference in log τ. The hold-local
random effects (o₁, o₂, δ) form a banded block (each bin touches its hold and the
previous one), so they are eliminated by a Schur complement with a banded Cholesky:

.. math::

    Σ_{gg} = (M_{gg} − M_{gb} M_{bb}^{-1} M_{bg})^{-1},\qquad g = (θ, c, d),\ b = (o, δ).

Derived quantities by the delta method, as the estimator reports them:
a = mean_j a_j(m_h + c) (eq. 10) and b_{j,0} = b_j + 2a(m₀ − m_h) (eq. 24, the scale
factor at the CCD centre), sd(q) = √(∇q Σ ∇qᵀ) with ∇q from JAX at the design values.

Everything that depends on the program is NumPy, so programs of any length cost no
compilation: one evaluation takes a few milliseconds (the grid of sensitivities is
computed once per instrument, ~1 s of JAX compilation).

**Clock time.** The simulator's and the acquisition's timing: a slew of the platform at
0.5°/s plus 3 s of platform settling before every hold whose attitude changes, then
``dwell_s`` of samples at 1 Hz. ``program_clock_s`` is that total; the search keeps it
within the budget (default: the given program's clock time).

**Search** (:func:`search_programs`): candidates described by a :class:`ProgramSpec`
(number of distinct angles, their spacing, the lowest angle, the order scheme, rounds,
settle time) inside the paper's range ±1°50′…±5°10′, each given the longest dwell
(whole seconds, at least ``min_dwell_s``) that fits the budget; a coarse grid over
(angles, rounds, settle) followed by a coordinate search (every coordinate in turn
over all its values, best first, until no coordinate improves) from the three best grid
points. The given program is always a candidate, so the result is never worse than it.

**Check against the estimator.** Given the hyperparameters that the MAP's EM settles on
for a simulated session (σ_o, σ_θ, noise scales, κ), this reproduces the Laplace sds it
reports for b₁, b₂, a and τ to better than 0.5 %; at the default design values (κ kept at
the estimator's starting 0.003, while EM on simulated records drives it to ~1e-4) it is
about 10 % above them (``tests/test_design.py``).
"""

from __future__ import annotations

import itertools
import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from scipy.interpolate import CubicSpline

import chekan.jaxconfig  # noqa: F401  (float64 before any array)
from chekan import model as fm
from chekan.calmodel import BIN_EDGES_S, nonlinear_params
from chekan.errors import ChekanError
from chekan.program import TiltProgram, build_program
from chekan.simulate import Truth
from chekan.units import ARCMIN_PER_RAD, ARCSEC_PER_RAD, format_dms

THETA_NAMES = ("b1", "b2", "K", "eps1_arcmin", "eps2_arcmin", "dgamma_arcmin", "tau_s")
C_PRIOR_VAR_PIX2 = 1.0  # chekan.calmodel.beta_prior_var: level offset c
DRIFT_PRIOR_VAR_PIX2 = 4.0  # … drift coefficients d
LOWEST_ANGLE_ARCMIN = 110  # 1°50′: the paper's smallest tilt
HIGHEST_ANGLE_ARCMIN = 310  # 5°10′: the paper's largest tilt
MIN_DWELL_S = 180.0  # search default: shortest dwell of a candidate
MIN_SETTLE_S = 120.0  # search default: 4τ; the lag is modelled, but only as first order
MIN_SETTLED_S = 60.0  # dwell − settle: samples after settling in every hold
OBJECTIVES = ("b_mean", "b_max", "a")
SCHEMES = {  # name → (order, sequence); "interleaved": as-given, largest/smallest alternating
    "paper": ("+-", "ascending"),
    "alternate": ("alternate", "ascending"),
    "zigzag": ("alternate", "zigzag"),
    "descending": ("+-", "descending"),
    "interleaved": ("+-", "as-given"),
}
_GRID_HALF_WIDTH_RAD = math.radians(6.5)  # beyond the 6° program limit: slews stay inside
_GRID_N = 2601  # 18″ spacing; spline error < 1e-10 pix


# ----------------------------------------------------------------------------- assumptions


@dataclass(frozen=True)
class DesignValues:
    """Design values of the instrument and of the estimator's error model.

    ``truth``: instrument, noise (``noise_pix`` per 1 Hz sample), hold offsets
    (``hold_offset_sd_pix``), angle readout (``angle_error_sd_arcsec``), damping lag
    (``tau_s``), slew speed and platform settling. The switches turn nuisances off (for
    analytic checks): ``hold_offsets``, ``angle_errors``, ``drift``, ``estimate_tau``;
    ``priors=False`` drops the priors of θ, c and d (flat).
    """

    truth: Truth = field(default_factory=Truth)
    slew_error: float = 0.003  # κ: chekan.calmodel.hyper_dict default
    drift_degree: int = 3
    bin_edges_s: tuple[float, ...] = BIN_EDGES_S
    hold_offsets: bool = True
    angle_errors: bool = True
    drift: bool = True
    estimate_tau: bool = True
    priors: bool = True


# ----------------------------------------------------------------------------- layout


@dataclass(frozen=True)
class Layout:
    """A program laid out at the sample rate the way a record of it is binned.

    Holds k = 0…H−1; slews (H, M) padded, ``slew_lag_s`` = t_last − t of each slew sample
    (t_last: the last sample before the hold); bins (N,) with their hold, the time from
    t_last to their first sample ``bin_d0_s`` (10⁹ for hold 0: settled from the start),
    sample count and mid time.
    """

    theta_hold_rad: np.ndarray
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
    """Attitudes of the samples of one move, as :func:`chekan.simulate.program_timeline`
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
    by :func:`chekan.calmodel.prepare_record` (settle time from the program)."""
    values = values or DesignValues()
    truth = values.truth
    dt = 1.0 / truth.sample_rate_hz
    steps = program.steps
    H = len(steps)
    theta = np.array([s.theta_rad for s in steps])
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


# ----------------------------------------------------------------------------- sensitivities


def _sensor_params(u, fixed, c=None) -> fm.SensorParams:
    """u = (b₁, b₂, log K, ε₁′, ε₂′, Δγ′); fixed = (g, m₀, m_h1, m_h2)."""
    m_level = fixed[2:4] if c is None else fixed[2:4] + c
    return fm.SensorParams(
        g_mgal=fixed[0],
        K_pix_per_rad=jnp.exp(u[2]),
        m0_pix=fixed[1],
        b_mgal_per_pix=u[0:2],
        m_level_pix=m_level,
        eps_rad=u[3:5] / ARCMIN_PER_RAD,
        gamma_rad=u[5] / ARCMIN_PER_RAD,
    )


@jax.jit
def _grid_sensitivities(u, fixed, theta_rad, direction):
    """E (n, 2), ∂E/∂u (n, 2, 6) and ∂E/∂θ (n, 2) along the program axis."""

    def eq(uu, th):
        p = _sensor_params(uu, fixed)
        return fm.equilibrium_readings(p, th * direction[0], th * direction[1])

    E = eq(u, theta_rad)
    dE_du = jax.jacfwd(eq, argnums=0)(u, theta_rad)
    S = jax.jvp(lambda th: eq(u, th), (theta_rad,), (jnp.ones_like(theta_rad),))[1]
    return E, dE_du, S


@jax.jit
def _derived(u, fixed):
    """(a, b₁,₀, b₂,₀) at the design values and their gradient in (u, c), (3,), (3, 8).

    a = mean_j a_j(m_h + c) (eq. 10), b_{j,0} = b_j + 2a_j(m₀ − m_h − c) (eq. 24), as
    :func:`chekan.bayes.map_derived` reports them.
    """

    def q(uc):
        p = _sensor_params(uc[:6], fixed, uc[6:])
        a = jnp.mean(fm.quadratic_coefficient(p, p.m_level_pix))
        b0 = fm.scale_factor_at_centre(p)
        return jnp.stack([a, b0[0], b0[1]])

    uc = jnp.concatenate([u, jnp.zeros(2)])
    return q(uc), jax.jacfwd(q)(uc)


@dataclass(frozen=True)
class Sensitivities:
    """Splines of E, ∂E/∂u and ∂E/∂θ over the signed tilt about one axis, plus the
    gradients of the derived quantities (a, b₁,₀, b₂,₀) in (u, c)."""

    spline: CubicSpline  # θ → 16 columns: E (2), ∂E/∂u (2 × 6, system-major), S (2)
    derived_grad: np.ndarray  # (3, 8)
    derived_value: np.ndarray  # (3,) a, b1_0, b2_0

    def at(self, theta_rad: np.ndarray):
        v = self.spline(np.asarray(theta_rad, dtype=float))
        sh = v.shape[:-1]
        return v[..., 0:2], v[..., 2:14].reshape(*sh, 2, 6), v[..., 14:16]


_SENS_CACHE: dict = {}


def _instrument_vectors(truth: Truth):
    u = np.array(
        [
            truth.b_mgal_per_pix[0],
            truth.b_mgal_per_pix[1],
            math.log(truth.K_pix_per_rad),
            truth.eps_arcmin[0],
            truth.eps_arcmin[1],
            truth.dgamma_arcmin,
        ],
        dtype=float,
    )
    fixed = np.array(
        [truth.g_local_mgal, truth.m0_pix, truth.m_level_pix[0], truth.m_level_pix[1]], float
    )
    return u, fixed


def sensitivities(truth: Truth, axis: str = "y") -> Sensitivities:
    """Grid of the exact equilibrium and its derivatives (one JAX call, cached)."""
    u, fixed = _instrument_vectors(truth)
    key = (tuple(u), tuple(fixed), axis)
    if key not in _SENS_CACHE:
        grid = np.linspace(-_GRID_HALF_WIDTH_RAD, _GRID_HALF_WIDTH_RAD, _GRID_N)
        direction = np.array([0.0, 1.0]) if axis == "y" else np.array([1.0, 0.0])
        E, dE, S = (np.asarray(x) for x in _grid_sensitivities(u, fixed, grid, direction))
        cols = np.concatenate([E, dE.reshape(_GRID_N, 12), S], axis=1)
        dval, dgrad = (np.asarray(x) for x in _derived(u, fixed))
        _SENS_CACHE[key] = Sensitivities(
            spline=CubicSpline(grid, cols, axis=0),
            derived_grad=dgrad,
            derived_value=dval,
        )
    return _SENS_CACHE[key]


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
    """Bin means of the lagged equilibrium (calmodel.linear_terms in NumPy).

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
    for k in range(1, H):
        base = wprev[k] * E_hold[k - 1] + Mv[k]
        R[k] = wprev[k] * rho[k - 1] * (y0 - E_hold[k - 1])
        y0 = base + R[k]
    k = layout.bin_hold
    n = layout.bin_n
    q = np.where(n > 1, -np.expm1(-n * dt / tau_s) / (n * -math.expm1(-dt / tau_s)), 1.0)
    w = np.exp(-layout.bin_d0_s / tau_s) * q
    kp = np.maximum(k - 1, 0)
    g_own = 1.0 - w
    g_prev = np.where(k > 0, w * wprev[k], 0.0)
    start = wprev[:, None, None] * np.concatenate([E_hold[:1], E_hold[:-1]]) + Mv + R  # y₀,ₖ
    f = g_own[:, None, None] * E_hold[k] + g_prev[:, None, None] * E_hold[kp]
    f = f + w[:, None, None] * (Mv[k] + R[k])
    trans = w[:, None] * np.abs(start[k, :, 0] - E_hold[k, :, 0])
    return Lagged(f=f, g_own=g_own, g_prev=g_prev, trans=trans)


# ----------------------------------------------------------------------------- information


@dataclass(frozen=True)
class ExpectedPrecision:
    """Expected posterior sds of a program at the design values."""

    program: TiltProgram
    sd: dict[str, float]  # b1, b2, a, b1_0, b2_0 and every θ (K and τ as values' sds)
    value: dict[str, float]  # design values of the same quantities
    clock_s: float
    n_holds: int
    n_bins: int

    def sd_ppm(self, name: str) -> float:
        """sd relative to the value, in ppm (b1, b2, b1_0, b2_0, a)."""
        return 1e6 * self.sd[name] / abs(self.value[name])

    def objective(self, name: str = "b_mean") -> float:
        """``b_mean``: mean sd of b₁, b₂; ``b_max``: the larger; ``a``: sd of a (mGal/pix²)."""
        if name == "b_mean":
            return 0.5 * (self.sd["b1"] + self.sd["b2"])
        if name == "b_max":
            return max(self.sd["b1"], self.sd["b2"])
        if name == "a":
            return self.sd["a"]
        raise ValueError(f"unknown objective {name!r}; choose one of {', '.join(OBJECTIVES)}")


def _global_columns(values: DesignValues, layout: Layout, df_du, df_dlogtau, j: int):
    """System j's columns that every bin can touch: ∂f/∂θ (7), c₁, c₂, drift (2D)."""
    N = layout.bin_hold.size
    D = values.drift_degree if values.drift else 0
    X = np.zeros((N, 9 + 2 * D))
    X[:, 0:6] = df_du[:, j, :]
    if values.estimate_tau:
        X[:, 6] = df_dlogtau[:, j]
    X[:, 7 + j] = 1.0
    if D:
        s = 2.0 * layout.bin_t_mid_s / max(layout.clock_s - layout.dt_s, 1.0) - 1.0
        X[:, 9 + j * D : 9 + (j + 1) * D] = np.polynomial.legendre.legvander(s, D)[:, 1:]
    return X


def _local_columns(values: DesignValues, layout: Layout, lag: Lagged, s_ang, j: int):
    """System j's hold-local columns as (indices, values) (N, 4): o_j and δ of the bin's
    hold (weight 1 − w) and of the previous hold (weight w·w_prev); unknowns ordered per
    hold as (o₁,ₖ, o₂,ₖ, δₖ) → index 3k + (j | 2)."""
    k = layout.bin_hold
    kp = np.maximum(k - 1, 0)
    use_o = 1.0 if values.hold_offsets else 0.0
    use_d = 1.0 if values.angle_errors else 0.0
    idx = np.stack([3 * k + j, 3 * k + 2, 3 * kp + j, 3 * kp + 2], axis=1)
    val = np.stack(
        [
            use_o * lag.g_own,
            use_d * lag.g_own * s_ang[k, j],
            use_o * lag.g_prev,
            use_d * lag.g_prev * s_ang[kp, j],
        ],
        axis=1,
    )
    return idx, val


_BAND = 5  # the unknowns of hold k touch those of hold k − 1 only: |row − column| ≤ 5


def information_blocks(program: TiltProgram, values: DesignValues | None = None):
    """Prior-augmented expected information in blocks: M_gg (g = θ, c, d), M_gb and M_bb
    in upper banded storage (b = o₁, o₂, δ per hold), plus the layout and sensitivities.

    M = Σⱼ Xⱼᵀ Wⱼ Xⱼ + Λ⁻¹ with the columns and weights of the module docstring.
    """
    values = values or DesignValues()
    truth = values.truth
    sens = sensitivities(truth, program.axis)
    layout = program_layout(program, values)
    H = layout.theta_hold_rad.size
    tau = float(truth.tau_s)
    E_h, dE_h, S_h = sens.at(layout.theta_hold_rad)
    E_s, dE_s, _ = sens.at(layout.slew_theta_rad)
    cols_h = np.concatenate([E_h[..., None], dE_h], axis=-1)  # (H, 2, 1 + 6)
    cols_s = np.concatenate([E_s[..., None], dE_s], axis=-1)  # (H, M, 2, 1 + 6)
    lag = lagged_means(layout, tau, cols_h, cols_s)
    h = 1e-4
    f_up = lagged_means(layout, tau * math.exp(h), cols_h[..., :1], cols_s[..., :1]).f[..., 0]
    f_dn = lagged_means(layout, tau * math.exp(-h), cols_h[..., :1], cols_s[..., :1]).f[..., 0]
    df_dlogtau = (f_up - f_dn) / (2.0 * h)
    noise = np.asarray(truth.noise_pix, dtype=float)
    var = noise[None, :] ** 2 / layout.bin_n[:, None] + (values.slew_error * lag.trans) ** 2
    W = 1.0 / var
    s_ang = -S_h / ARCSEC_PER_RAD  # (H, 2) pix per arcsec of readout error

    ng = 9 + 2 * (values.drift_degree if values.drift else 0)
    nb = 3 * H
    Mgg = np.zeros((ng, ng))
    gb_pos, gb_w, bb_pos, bb_w = [], [], [], []
    for j in range(2):
        X = _global_columns(values, layout, lag.f[..., 1:], df_dlogtau, j)
        idx, val = _local_columns(values, layout, lag, s_ang, j)
        Wj = W[:, j]
        Mgg += X.T @ (X * Wj[:, None])
        wv = val * Wj[:, None]  # (N, 4)
        gb_pos.append((np.arange(ng)[None, None, :] * nb + idx[:, :, None]).ravel())
        gb_w.append((wv[:, :, None] * X[:, None, :]).ravel())
        r, c = idx[:, :, None], idx[:, None, :]
        upper = np.broadcast_to(r <= c, (idx.shape[0], 4, 4))
        pos = (_BAND + r - c) * nb + c
        bb_pos.append(pos[upper])
        bb_w.append((wv[:, :, None] * val[:, None, :])[upper])
    Mgb = np.bincount(np.concatenate(gb_pos), np.concatenate(gb_w), minlength=ng * nb).reshape(
        ng, nb
    )
    ab = np.bincount(
        np.concatenate(bb_pos), np.concatenate(bb_w), minlength=(_BAND + 1) * nb
    ).reshape(_BAND + 1, nb)
    # priors (Λ⁻¹); switched-off random effects keep a unit precision: their columns are zero
    prec_g = np.zeros(ng)
    if values.priors:
        prec_g[:7] = [1.0 / p.scale**2 for p in nonlinear_params()]
        prec_g[7:9] = 1.0 / C_PRIOR_VAR_PIX2
        prec_g[9:] = 1.0 / DRIFT_PRIOR_VAR_PIX2
    if not values.estimate_tau:
        prec_g[6] = 1.0
    Mgg += np.diag(prec_g)
    so2 = truth.hold_offset_sd_pix**2 if values.hold_offsets else 1.0
    st2 = truth.angle_error_sd_arcsec**2 if values.angle_errors else 1.0
    ab[_BAND] += np.tile([1.0 / so2, 1.0 / so2, 1.0 / st2], H)
    return Mgg, Mgb, ab, layout, sens


def expected_precision(
    program: TiltProgram, values: DesignValues | None = None
) -> ExpectedPrecision:
    """Expected posterior sd of b₁, b₂, a, b₁,₀, b₂,₀ and θ for ``program`` (module doc):
    Σ_gg = (M_gg − M_gb M_bb⁻¹ M_bg)⁻¹, derived quantities by the delta method."""
    values = values or DesignValues()
    truth = values.truth
    Mgg, Mgb, ab, layout, sens = information_blocks(program, values)
    Y = scipy.linalg.solveh_banded(ab, Mgb.T, lower=False, check_finite=False)
    cov = scipy.linalg.inv(Mgg - Mgb @ Y, check_finite=False)
    cov_tc = cov[:9, :9]  # (θ, c)
    sd = {name: math.sqrt(max(cov_tc[i, i], 0.0)) for i, name in enumerate(THETA_NAMES)}
    Jd = np.zeros((3, 9))  # ∇(a, b₁,₀, b₂,₀) over (θ, c); τ does not enter
    Jd[:, :6] = sens.derived_grad[:, :6]
    Jd[:, 7:9] = sens.derived_grad[:, 6:8]
    dvar = np.einsum("ij,jk,ik->i", Jd, cov_tc, Jd)
    for i, name in enumerate(("a", "b1_0", "b2_0")):
        sd[name] = math.sqrt(max(dvar[i], 0.0))
    sd["K"] *= truth.K_pix_per_rad  # sd of the value from the sd of its log
    sd["tau_s"] *= truth.tau_s
    value = {
        "b1": float(truth.b_mgal_per_pix[0]),
        "b2": float(truth.b_mgal_per_pix[1]),
        "a": float(sens.derived_value[0]),
        "b1_0": float(sens.derived_value[1]),
        "b2_0": float(sens.derived_value[2]),
        "K": float(truth.K_pix_per_rad),
        "eps1_arcmin": float(truth.eps_arcmin[0]),
        "eps2_arcmin": float(truth.eps_arcmin[1]),
        "dgamma_arcmin": float(truth.dgamma_arcmin),
        "tau_s": float(truth.tau_s),
    }
    return ExpectedPrecision(
        program, sd, value, layout.clock_s, layout.theta_hold_rad.size, layout.bin_hold.size
    )


# ----------------------------------------------------------------------------- search


@dataclass(frozen=True)
class ProgramSpec:
    """A candidate program, described by the coordinates the search moves along.

    Angles: ``n_angles`` magnitudes from ``lowest_arcmin`` to 5°10′, equally spaced in
    Δg ∝ 1 − cos θ (``spacing="dg"``, the paper's rule: "Δg grows by about 500 mGal from one
    angle to the next") or in θ (``"angle"``), rounded to whole arcminutes. ``scheme``: the
    order of the holds (:data:`SCHEMES`): "paper" (+θ, −θ pairs ascending), "alternate"
    (+− in odd rounds, −+ in even), "zigzag" (alternate, and ascending/descending by
    round), "descending", "interleaved" (largest, smallest, second largest, … : angle
    uncorrelated with time). The dwell is not a coordinate: it is the longest (whole
    seconds) that fits the budget.
    """

    n_angles: int = 8
    spacing: str = "dg"
    lowest_arcmin: int = LOWEST_ANGLE_ARCMIN
    scheme: str = "paper"
    rounds: int = 2
    settle_s: float = 300.0

    def label(self) -> str:
        return (
            f"{self.n_angles} angles ({self.spacing}, from {format_dms(self.lowest_arcmin / 60)}), "
            f"{self.scheme}, {self.rounds} round(s), settle {self.settle_s:g} s"
        )


SEARCH_SPACE: dict[str, tuple] = {
    "n_angles": (2, 3, 4, 5, 6, 8, 10, 12, 16),
    "spacing": ("dg", "angle"),
    "lowest_arcmin": (110, 150, 190, 230, 270),
    "scheme": tuple(SCHEMES),
    "rounds": (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24),
    "settle_s": (60.0, 90.0, 120.0, 180.0, 240.0, 300.0),
}


def spec_angles_arcmin(spec: ProgramSpec) -> list[int]:
    """The distinct tilt magnitudes of a spec in whole arcminutes, ascending (may be fewer
    than ``n_angles`` when rounding merges two)."""
    lo, hi = spec.lowest_arcmin, HIGHEST_ANGLE_ARCMIN
    if spec.n_angles == 1 or lo >= hi:
        return [hi]
    if spec.spacing == "dg":
        x = np.linspace(
            1 - math.cos(math.radians(lo / 60)), 1 - math.cos(math.radians(hi / 60)), spec.n_angles
        )
        theta_arcmin = np.degrees(np.arccos(1 - x)) * 60
    elif spec.spacing == "angle":
        theta_arcmin = np.linspace(lo, hi, spec.n_angles)
    else:
        raise ValueError(f"unknown spacing {spec.spacing!r}")
    return sorted({round(float(a)) for a in theta_arcmin})


def _interleave(values: list) -> list:
    """largest, smallest, second largest, second smallest, …"""
    out, lo, hi = [], 0, len(values) - 1
    while lo <= hi:
        out.append(values[hi])
        if lo != hi:
            out.append(values[lo])
        lo, hi = lo + 1, hi - 1
    return out


def program_within_budget(
    angles_deg,
    budget_s: float,
    *,
    settle_s: float,
    rounds: int,
    order: str = "+-",
    sequence: str = "ascending",
    axis: str = "y",
    name: str | None = None,
    values: DesignValues | None = None,
    min_dwell_s: float = MIN_DWELL_S,
) -> TiltProgram | None:
    """The program with these angles and order and the longest dwell (whole seconds) whose
    clock time with slews fits ``budget_s``: dwell = ⌊(budget − slews)/steps⌋. None when
    that dwell is below ``min_dwell_s`` or leaves less than ``MIN_SETTLED_S`` after
    ``settle_s``."""
    kw = dict(axis=axis, order=order, sequence=sequence, rounds=rounds)
    probe = build_program(angles_deg, dwell_s=1.0, settle_s=0.0, **kw)
    slew_s = program_clock_s(probe, values) - probe.duration_s  # moves do not depend on dwell
    dwell = float(math.floor((budget_s - slew_s) / probe.n_steps))
    if dwell < min_dwell_s or dwell - settle_s < MIN_SETTLED_S:
        return None
    name = name or f"design-{len(probe.angles_rad)}x{rounds}-{dwell:g}s"
    return build_program(angles_deg, name=name, dwell_s=dwell, settle_s=settle_s, **kw)


def spec_program(
    spec: ProgramSpec,
    budget_s: float,
    *,
    axis: str = "y",
    values: DesignValues | None = None,
    min_dwell_s: float = MIN_DWELL_S,
) -> TiltProgram | None:
    """The program of a spec (:func:`program_within_budget`); None when rounding to whole
    arcminutes merged two angles or the dwell does not fit."""
    angles = spec_angles_arcmin(spec)
    if len(angles) < spec.n_angles:
        return None
    order, sequence = SCHEMES[spec.scheme]
    if spec.scheme == "interleaved":
        angles = _interleave(angles)
    return program_within_budget(
        [a / 60.0 for a in angles],
        budget_s,
        settle_s=spec.settle_s,
        rounds=spec.rounds,
        order=order,
        sequence=sequence,
        axis=axis,
        values=values,
        min_dwell_s=min_dwell_s,
    )


@dataclass(frozen=True)
class Candidate:
    """One evaluated program: its spec (None for the given program) and precision."""

    spec: ProgramSpec | None
    precision: ExpectedPrecision
    objective: float

    @property
    def program(self) -> TiltProgram:
        return self.precision.program


@dataclass(frozen=True)
class SearchResult:
    """Candidates ranked by the objective (best first); ``given`` is the input program,
    ranked with the rest for comparison even when it does not fit a smaller budget."""

    given: Candidate
    ranked: list[Candidate]
    objective: str
    budget_s: float
    evaluations: int
    seconds: float

    def fits(self, c: Candidate) -> bool:
        return c.precision.clock_s <= self.budget_s + 1e-6

    @property
    def best(self) -> Candidate:
        """The best candidate within the budget (ChekanError when none fits)."""
        for c in self.ranked:
            if self.fits(c):
                return c
        raise ChekanError(
            f"no program fits {self.budget_s / 3600:.2f} h with dwells ≥ the minimum; "
            "raise --budget-h or lower --min-dwell-s/--min-settle-s"
        )


def _spec_key(spec: ProgramSpec) -> tuple:
    return tuple(getattr(spec, k) for k in SEARCH_SPACE)


def search_programs(
    program: TiltProgram,
    *,
    budget_s: float | None = None,
    objective: str = "b_mean",
    values: DesignValues | None = None,
    space: dict[str, tuple] | None = None,
    min_dwell_s: float = MIN_DWELL_S,
    min_settle_s: float = MIN_SETTLE_S,
    start_points: int = 3,
    max_sweeps: int = 4,
) -> SearchResult:
    """Search for a program with a smaller expected sd within a clock-time budget.

    1. the given program (always a candidate: the result is never worse);
    2. a grid over (``n_angles``, ``rounds``, ``settle_s``) with the other coordinates at
       the paper's choices (Δg spacing from 1°50′, paper order);
    3. coordinate search from the ``start_points`` best grid points: each coordinate of
       ``space`` in turn is set to every one of its values, the best is kept, until a
       sweep improves nothing (at most ``max_sweeps``).

    Every candidate gets the longest dwell that fits ``budget_s`` (default: the given
    program's clock time, :func:`program_clock_s`), at least ``min_dwell_s``, with a settle
    time of at least ``min_settle_s``. Under the estimator's model every hold brings an
    independent offset and angle error, so the sd falls roughly as 1/√(number of holds)
    and the search runs to the shortest dwell allowed: the two limits are where the
    engineering judgement goes (how far the first-order lag can be trusted).
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; choose one of {', '.join(OBJECTIVES)}")
    values = values or DesignValues()
    space = dict(space or SEARCH_SPACE)
    space["settle_s"] = tuple(
        sorted({float(min_settle_s)} | {float(x) for x in space["settle_s"] if x >= min_settle_s})
    )
    t0 = time.perf_counter()
    budget = float(budget_s) if budget_s is not None else program_clock_s(program, values)
    given_prec = expected_precision(program, values)
    given = Candidate(None, given_prec, given_prec.objective(objective))
    seen: dict[tuple, Candidate | None] = {}

    def evaluate(spec: ProgramSpec) -> Candidate | None:
        key = _spec_key(spec)
        if key not in seen:
            prog = spec_program(
                spec, budget, axis=program.axis, values=values, min_dwell_s=min_dwell_s
            )
            if prog is None:
                seen[key] = None
            else:
                prec = expected_precision(prog, values)
                seen[key] = Candidate(spec, prec, prec.objective(objective))
        return seen[key]

    base = ProgramSpec(settle_s=space["settle_s"][-1])
    grid = [
        replace(base, n_angles=n, rounds=r, settle_s=st)
        for n in space["n_angles"]
        for r in space["rounds"]
        for st in space["settle_s"]
    ]
    scored = sorted((c for c in map(evaluate, grid) if c is not None), key=lambda c: c.objective)
    for current in scored[:start_points]:
        for _ in range(max_sweeps):
            improved = False
            for name, options in space.items():
                for opt in options:
                    c = evaluate(replace(current.spec, **{name: opt}))
                    if c is not None and c.objective < current.objective * (1 - 1e-9):
                        current, improved = c, True
            if not improved:
                break
    evaluated = [c for c in seen.values() if c is not None]
    ranked = sorted([given, *evaluated], key=lambda c: c.objective)
    return SearchResult(
        given=given,
        ranked=ranked,
        objective=objective,
        budget_s=budget,
        evaluations=1 + len(evaluated),
        seconds=time.perf_counter() - t0,
    )


# ----------------------------------------------------------------------------- output


def format_precision(prec: ExpectedPrecision) -> str:
    """The expected sds of b₁, b₂ (at the level reading and at the CCD centre) and a."""
    p = prec.program
    lines = [
        f"{p.describe()}",
        f"clock time with slews {prec.clock_s / 3600:.2f} h; {prec.n_holds} holds, "
        f"{prec.n_bins} bins per system",
        "expected posterior sd (Laplace, at the design values):",
    ]
    for name, what in (
        ("b1", "b1 (level reading)"),
        ("b2", "b2 (level reading)"),
        ("b1_0", "b1 at the CCD centre"),
        ("b2_0", "b2 at the CCD centre"),
    ):
        lines.append(
            f"  {what:<22} {prec.sd[name]:.3e} mGal/pix   ({prec.sd_ppm(name):6.1f} ppm of "
            f"{prec.value[name]:.4f})"
        )
    lines.append(
        f"  {'a':<22} {prec.sd['a']:.3e} mGal/pix^2 ({prec.sd_ppm('a'):6.0f} ppm of "
        f"{prec.value['a']:.4e})"
    )
    lines.append(
        f"  also: tau {prec.sd['tau_s']:.2g} s, eps1 {prec.sd['eps1_arcmin']:.2g}', "
        f"eps2 {prec.sd['eps2_arcmin']:.2g}', dgamma {prec.sd['dgamma_arcmin']:.2g}'"
    )
    return "\n".join(lines)


def candidate_row(c: Candidate) -> dict:
    """One row of the ranked table (plain numbers, JSON-ready)."""
    p, prec = c.program, c.precision
    return {
        "name": p.name,
        "given": c.spec is None,
        "angles": [format_dms(math.degrees(a)) for a in p.angles_rad],
        "n_angles": len(p.angles_rad),
        "order": p.order,
        "sequence": p.sequence,
        "rounds": p.rounds,
        "dwell_s": p.dwell_s,
        "settle_s": p.settle_s,
        "n_steps": p.n_steps,
        "clock_h": prec.clock_s / 3600.0,
        "sd_b1_mgal_per_pix": prec.sd["b1"],
        "sd_b2_mgal_per_pix": prec.sd["b2"],
        "sd_a_mgal_per_pix2": prec.sd["a"],
        "sd_b1_ppm": prec.sd_ppm("b1"),
        "sd_b2_ppm": prec.sd_ppm("b2"),
        "objective": c.objective,
    }


def format_table(result: SearchResult, top: int = 15) -> str:
    """Ranked table of the best ``top`` candidates (and the given program wherever it is)."""
    cols = (
        ("#", 3),
        ("angles", -18),
        ("spacing", -7),
        ("order", -9),
        ("sequence", -10),
        ("rounds", 6),
        ("dwell", 6),
        ("settle", 6),
        ("steps", 5),
        ("clock h", 7),
        ("sd b1 ppm", 9),
        ("sd b2 ppm", 9),
        ("sd a", 9),
    )

    def line(cells) -> str:
        pairs = zip(cells, (w for _, w in cols), strict=True)
        return " ".join(f"{c:<{-w}}" if w < 0 else f"{c:>{w}}" for c, w in pairs)

    lines = [line([name for name, _ in cols])]
    for i, c in enumerate(result.ranked):
        if i >= top and c is not result.given:
            continue
        r = candidate_row(c)
        lo, hi = min(r["angles"], key=_dms_key), max(r["angles"], key=_dms_key)
        spacing = {"dg": "Δg", "angle": "θ"}[c.spec.spacing] if c.spec else "given"
        cells = (
            i + 1,
            f"{r['n_angles']} {lo}..{hi}",
            spacing,
            r["order"],
            r["sequence"],
            r["rounds"],
            f"{r['dwell_s']:g}",
            f"{r['settle_s']:g}",
            r["n_steps"],
            f"{r['clock_h']:.2f}",
            f"{r['sd_b1_ppm']:.1f}",
            f"{r['sd_b2_ppm']:.1f}",
            f"{r['sd_a_mgal_per_pix2']:.2e}",
        )
        note = "  <- given" if r["given"] else ""
        if r["given"] and not result.fits(c):
            note += " (over the budget)"
        lines.append(line(cells) + note)
    return "\n".join(lines)


def _dms_key(text: str) -> float:
    from chekan.units import parse_angle_deg

    return parse_angle_deg(text)


def program_toml(program: TiltProgram) -> str:
    """A TOML program file that :func:`chekan.program.load_program` reads back to the same
    program (angles in whole arcminutes as DMS text, otherwise as decimal degrees)."""

    def angle_text(a_rad: float) -> str:
        deg = math.degrees(a_rad)
        arcmin = deg * 60.0
        if abs(arcmin - round(arcmin)) < 1e-9:
            return json.dumps(format_dms(deg), ensure_ascii=False)
        return json.dumps(repr(deg))

    angles = ", ".join(angle_text(a) for a in program.angles_rad)
    return (
        f"# written by chekan design ({program_clock_s(program) / 3600:.2f} h with slews)\n"
        f"name = {json.dumps(program.name, ensure_ascii=False)}\n"
        f"angles = [{angles}]\n"
        f"axis = {json.dumps(program.axis)}\n"
        f"order = {json.dumps(program.order)}\n"
        f"sequence = {json.dumps(program.sequence)}\n"
        f"dwell_s = {program.dwell_s:g}\n"
        f"settle_s = {program.settle_s:g}\n"
        f"rounds = {program.rounds}\n"
    )


def write_program_toml(path: str | Path, program: TiltProgram) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(program_toml(program), encoding="utf-8")
    return path


def precision_json(prec: ExpectedPrecision) -> dict:
    return {
        "program": prec.program.describe(),
        "clock_h": prec.clock_s / 3600.0,
        "n_holds": prec.n_holds,
        "sd": dict(prec.sd),
        "value": dict(prec.value),
        "sd_ppm": {k: prec.sd_ppm(k) for k in ("b1", "b2", "b1_0", "b2_0", "a")},
    }


def design_json(prec: ExpectedPrecision, result: SearchResult | None, values: DesignValues) -> dict:
    """Everything ``chekan design --json`` writes."""
    t = values.truth
    out = {
        "format": "chekan-design/1",
        "assumptions": {
            "noise_pix_per_sample": list(t.noise_pix),
            "hold_offset_sd_pix": t.hold_offset_sd_pix,
            "angle_error_sd_arcsec": t.angle_error_sd_arcsec,
            "tau_s": t.tau_s,
            "slew_error": values.slew_error,
            "drift_degree": values.drift_degree,
            "slew_deg_per_s": t.slew_deg_per_s,
        },
        "given": precision_json(prec),
    }
    if result is not None:
        out["search"] = {
            "objective": result.objective,
            "budget_h": result.budget_s / 3600.0,
            "evaluations": result.evaluations,
            "seconds": result.seconds,
            "best": precision_json(result.best.precision),
            "best_toml": program_toml(result.best.program),
            "ranked": [candidate_row(c) for c in result.ranked],
        }
    return out


# ----------------------------------------------------------------------------- command


def run_design_command(args) -> int:
    """``chekan design [PROGRAM.toml] [--budget-h H] [--search] [--out best.toml] [--json J]``."""
    from chekan.program import default_program, load_program

    program = load_program(args.program) if args.program else default_program()
    values = DesignValues()
    t0 = time.perf_counter()
    prec = expected_precision(program, values)
    print(f"given program ({args.program or 'the paper’s default'}):")
    print(format_precision(prec))
    print(
        f"(design model evaluated in {1e3 * (time.perf_counter() - t0):.0f} ms, first call "
        "includes the one-off JAX grid)"
    )
    result = None
    if args.search or args.out:
        budget_s = args.budget_h * 3600.0 if args.budget_h else None
        result = search_programs(
            program,
            budget_s=budget_s,
            objective=args.objective,
            values=values,
            min_dwell_s=args.min_dwell_s,
            min_settle_s=args.min_settle_s,
        )
        print(
            f"\nsearch: {result.evaluations} programs within {result.budget_s / 3600:.2f} h "
            f"(clock time with slews), objective {result.objective}, "
            f"{result.seconds:.1f} s ({1e3 * result.seconds / result.evaluations:.0f} ms each)"
        )
        print(format_table(result, top=args.top))
        best = result.best
        if best.spec is None:
            print("\nthe given program is the best found")
        else:
            gain = result.given.objective / best.objective
            print(f"\nbest: {best.spec.label()}, dwell {best.program.dwell_s:g} s")
            print(format_precision(best.precision))
            print(f"objective {result.objective}: {gain:.2f}× smaller sd than the given program")
        if args.out:
            written = write_program_toml(args.out, best.program)
            print(f"wrote {written} (best program; chekan program {written} shows it)")
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(
            json.dumps(design_json(prec, result, values), indent=2, ensure_ascii=False) + "\n",
            encoding="utf-8",
        )
        print(f"wrote {path}")
    return 0
