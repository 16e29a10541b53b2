r"""Expected information of a tilt program: the expected precision of b₁, b₂ and a.

**What is computed.** For a tilt program and design values of the instrument (default:
:class:`chekan.records.simulate.Truth`, the simulator's instrument and error budget), the Laplace
covariance that the MAP estimator (:mod:`chekan.joint`) would report, evaluated at the
design values with every random effect at its prior mean:

.. math::

    \Sigma = \Big(\sum_{j=1,2} X_jᵀ W_j X_j + Λ^{-1}\Big)^{-1},
    \qquad X_j = [\,∂f_j/∂θ,\ 1,\ P,\ G,\ G\,\mathrm{diag}(s_j)\,],

the inverse of the expected information of the joint record model of
:mod:`chekan.joint`, whose data are bin means inside every hold (bins 0–15–40–90–180 s
and ``settle_s`` across the settling transient, one bin after it):

.. math::

    ȳ_{ij} = f_{ij}(θ) + c_j + P(s_i)\,d_j + G_i\,(o_j + s_j ∘ δ) + e_{ij},\qquad
    e_{ij} \sim N\big(0,\ σ_j^2/n_i + (κ\,\mathrm{trans}_{ij})^2\big).

θ = (b₁, b₂, log K, ε₁, ε₂, Δγ, log τ) (the estimator's nonlinear parameters with their
priors from :func:`chekan.joint.problem.nonlinear_params`); f = G E + w(M_v + R) is the lagged
exact torsion equilibrium (E at every hold, :func:`chekan.physics.sensor.equilibrium_readings`,
first-order damping lag τ, the lag state after each slew filtered along the slew's
attitudes, the unsettled remainder R carried across holds); G is the (N × H) lag-mixing
matrix (1 − wᵢ on the bin's own hold, wᵢ w_prev on the previous one); c_j the level offset
(prior 1 pix²), d_j a Legendre drift of degree 3 without constant (prior 4 pix²), o_j the
per-hold offsets (prior σ_o² = 0.08²), δ the per-hold angle-readout errors **shared by both
systems** (prior σ_θ² = (2″)²) entering through s_j = −∂E_j/∂θ / 206265 (pix/″); n_i is the
bin's sample count, σ_j the 1 Hz noise (0.15 pix), κ the slew error (0.003) times the
transient still present in the bin. W_j = diag(1/var e_{·j}); Λ the prior covariance.

**Systematic angle errors** (:mod:`chekan.joint.angles`): the angle error of hold k is
δₖ + (Bζ)ₖ, B the estimator's basis built per axis sensor (:func:`systematic_basis`):
an indicator per distinct commanded signed angle (level included) and the scale θₖ/θ_max,
for the Y sensor's holds and, separately, the X sensor's (a program with ``axis="xy"``
alternates rounds about Y and X); along the slews the scale error and one term per slew
type (:mod:`chekan.joint.slews`). These terms, shared by all rounds, and the X response
beyond eq. (6) (:func:`x_response_columns`) enter as global columns exactly as the
equilibria they shift: through the lag state after each slew and the unsettled carry
across holds (:func:`lagged_means` on their columns, as the estimator does), with the
specification's Type B prior (u²/2 each for the 3″ default); ``angle_bound_arcsec=0``
leaves them out (the previous model exactly).

The Jacobian ∂f/∂θ is exact for the instrument parameters (f is linear in E, so
∂f/∂u = f evaluated on ∂E/∂u, from JAX forward-mode on a fixed grid of attitudes and a
cubic spline, error < 1e-10 pix) and a central difference in log τ. The hold-local
random effects (o₁, o₂, δ) form a banded block (each bin touches its hold and the
previous one), so they are eliminated by a Schur complement with a banded Cholesky:

.. math::

    Σ_{gg} = (M_{gg} − M_{gb} M_{bb}^{-1} M_{bg})^{-1},\qquad g = (θ, c, d, ζ),\ b = (o, δ).

Derived quantities by the delta method, as the estimator reports them:
a = mean_j a_j(m_h + c) (eq. 10) and b_{j,0} = b_j + 2a(m₀ − m_h) (eq. 24, the scale
factor at the CCD centre), sd(q) = √(∇q Σ ∇qᵀ) with ∇q from JAX at the design values.

Everything that depends on the program is NumPy, so programs of any length cost no
compilation: one evaluation takes a few milliseconds (the grid of sensitivities is
computed once per instrument, ~1 s of JAX compilation).

**Check against the estimator.** Given the hyperparameters that the MAP's EM settles on
for a simulated session (σ_o, σ_θ, noise scales, κ), this reproduces the Laplace sds it
reports for b₁, b₂, a and τ to better than 0.5 %; at the default design values (κ kept at
the estimator's starting 0.003, while EM on simulated records drives it to ~1e-4) it is
about 10 % above them (``tests/test_design.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.sparse
from scipy.interpolate import CubicSpline

import chekan.jaxconfig  # noqa: F401  (float64 before any array)
from chekan.design.layout import DesignValues, Lagged, Layout, lagged_means, program_layout
from chekan.joint.angles import SensorReads, all_sensor_terms
from chekan.joint.derived import at_horizontal
from chekan.joint.problem import nonlinear_params
from chekan.joint.slews import slew_types, types_about
from chekan.joint.xresponse import M0_TOLERANCE_PIX, horizontal_prior, x_response_terms
from chekan.physics import sensor as fm
from chekan.physics.program import TiltProgram
from chekan.physics.units import ARCMIN_PER_RAD, ARCSEC_PER_RAD
from chekan.records.simulate import Truth
from chekan.runtime import cached, jit

THETA_NAMES = ("b1", "b2", "K", "eps1_arcmin", "eps2_arcmin", "dgamma_arcmin", "tau_s")
C_PRIOR_VAR_PIX2 = 1.0  # chekan.joint.likelihood.beta_prior_var: level offset c
DRIFT_PRIOR_VAR_PIX2 = 4.0  # … drift coefficients d
OBJECTIVES = ("b_mean", "b_max", "a")
_GRID_HALF_WIDTH_RAD = math.radians(6.5)  # beyond the 6° program limit: slews stay inside
_GRID_N = 2601  # 18″ spacing; spline error < 1e-10 pix


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


@jit
def _grid_sensitivities(u, fixed, theta_rad, direction):
    """E (n, 2), ∂E/∂u (n, 2, 6) and ∂E/∂θ (n, 2) along the program axis."""

    def eq(uu, th):
        p = _sensor_params(uu, fixed)
        return fm.equilibrium_readings(p, th * direction[0], th * direction[1])

    E = eq(u, theta_rad)
    dE_du = jax.jacfwd(eq, argnums=0)(u, theta_rad)
    S = jax.jvp(lambda th: eq(u, th), (theta_rad,), (jnp.ones_like(theta_rad),))[1]
    return E, dE_du, S


@jit
def _derived(u, fixed):
    """(a, b₁,₀, b₂,₀) at the design values and their gradient in (u, c, Δm₀), (3,), (3, 10).

    a = mean_j a_j(m_h + c) with each pendulum's horizontal at m₀ + Δm₀ⱼ (eq. 10),
    b_{j,0} = b_j + 2a_j(m₀ − m_h − c) (eq. 24), as
    :func:`chekan.joint.derived.physical_quantities` reports them (Δm₀ enters where the
    program tilts about X: :mod:`chekan.joint.xresponse`).
    """

    def q(ucd):
        a, b0 = at_horizontal(_sensor_params(ucd[:6], fixed, ucd[6:8]), ucd[8:10])
        return jnp.stack([a, b0[0], b0[1]])

    ucd = jnp.concatenate([u, jnp.zeros(4)])
    return q(ucd), jax.jacfwd(q)(ucd)


@dataclass(frozen=True)
class Sensitivities:
    """Splines of E, ∂E/∂u and ∂E/∂θ over the signed tilt about one axis, plus the
    gradients of the derived quantities (a, b₁,₀, b₂,₀) in (u, c, Δm₀)."""

    spline: CubicSpline  # θ → 16 columns: E (2), ∂E/∂u (2 × 6, system-major), S (2)
    derived_grad: np.ndarray  # (3, 10) over (u, c, Δm₀)
    derived_value: np.ndarray  # (3,) a, b1_0, b2_0

    def at(self, theta_rad: np.ndarray):
        v = self.spline(np.asarray(theta_rad, dtype=float))
        sh = v.shape[:-1]
        return v[..., 0:2], v[..., 2:14].reshape(*sh, 2, 6), v[..., 14:16]


#: instruments whose sensitivities are kept (a design search asks for one or two)
MAX_SENSITIVITIES = 16


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
    """Grid of the exact equilibrium and its derivatives (one JAX call, cached: the last
    ``MAX_SENSITIVITIES`` instruments, cleared by :func:`chekan.runtime.clear_caches`)."""
    u, fixed = _instrument_vectors(truth)
    return _sensitivities(tuple(u), tuple(fixed), axis)


@cached(maxsize=MAX_SENSITIVITIES)
def _sensitivities(u_key: tuple, fixed_key: tuple, axis: str) -> Sensitivities:
    u, fixed = np.array(u_key, dtype=float), np.array(fixed_key, dtype=float)
    grid = np.linspace(-_GRID_HALF_WIDTH_RAD, _GRID_HALF_WIDTH_RAD, _GRID_N)
    direction = np.array([0.0, 1.0]) if axis == "y" else np.array([1.0, 0.0])
    E, dE, S = (np.asarray(x) for x in _grid_sensitivities(u, fixed, grid, direction))
    cols = np.concatenate([E, dE.reshape(_GRID_N, 12), S], axis=1)
    dval, dgrad = (np.asarray(x) for x in _derived(u, fixed))
    return Sensitivities(
        spline=CubicSpline(grid, cols, axis=0),
        derived_grad=dgrad,
        derived_value=dval,
    )


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


def systematic_basis(
    layout: Layout, values: DesignValues
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The systematic angle-error terms at the holds B (H, Q) and along the slews
    (H, M, Q), in arcsec per unit, and their prior variances (Q,): for each axis sensor the
    program uses, the estimator's terms (:func:`chekan.joint.angles.sensor_terms`: one per
    distinct commanded signed angle, level included, the scale error, and one per slew
    type along the slews; a tilt about X is read by the other sensor, with its own terms,
    and the scale error the two may share), each sensor with its table where
    ``values.angle_calibration`` has one, else the bound. Empty when neither is modelled
    (``angle_bound_arcsec`` 0, no table)."""
    H = layout.theta_hold_rad.size
    if not values.systematic:
        return np.zeros((H, 0)), np.zeros((*layout.slew_theta_rad.shape, 0)), np.zeros(0)
    types = slew_types(
        layout.theta_hold_rad, layout.hold_axis, np.asarray(layout.slew_mask.any(axis=1))
    )
    sensors = {}
    for axis in ("x", "y"):
        on = layout.hold_axis == axis
        if not on.any():
            continue
        kinds, T = types_about(types, layout.hold_axis, axis)
        path_on = (layout.hold_axis == axis)[:, None] & layout.slew_mask
        spec = values.angle_spec_of(axis)
        sensors[axis] = SensorReads(on, layout.slew_theta_rad, path_on, kinds, T, spec)
    hold, path, var, _, _ = all_sensor_terms(
        layout.theta_hold_rad, sensors, layout.slew_theta_rad.shape
    )
    return hold, path, var


def x_response_columns(
    layout: Layout, truth: Truth, horizontal_u_pix: float = M0_TOLERANCE_PIX
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The estimator's X-response terms (:func:`chekan.joint.xresponse.x_response_terms`)
    at the holds (H, C), along the slews (H, M, C) and their prior variances (C,)."""
    types = slew_types(
        layout.theta_hold_rad, layout.hold_axis, np.asarray(layout.slew_mask.any(axis=1))
    )
    kinds, T = types_about(types, layout.hold_axis, "x")
    path_on = (layout.hold_axis == "x")[:, None] & layout.slew_mask
    return x_response_terms(
        layout.theta_hold_rad,
        layout.hold_axis,
        truth.g_local_mgal,
        layout.slew_theta_rad,
        path_on,
        kinds,
        T,
        m_level_pix=float(np.mean(truth.m_level_pix)),
        m0_pix=float(truth.m0_pix),
        m0_u_pix=horizontal_u_pix,
    )


def _hold_sensitivities(layout: Layout, truth: Truth):
    """E, ∂E/∂u and S at the holds and along the slews into them, each from the grid of
    the hold's own axis (a slew is on the axis of the hold it leads to)."""
    axes = sorted(set(layout.hold_axis.tolist()))
    first = sensitivities(truth, layout.hold_axis[0])
    at_h, at_s = first.at(layout.theta_hold_rad), first.at(layout.slew_theta_rad)
    if len(axes) == 1:
        return first, at_h, at_s
    at_h, at_s = [np.array(x) for x in at_h], [np.array(x) for x in at_s]
    for a in axes:
        on = layout.hold_axis == a
        sens = sensitivities(truth, a)
        for out, new in zip(at_h, sens.at(layout.theta_hold_rad[on]), strict=True):
            out[on] = new
        for out, new in zip(at_s, sens.at(layout.slew_theta_rad[on]), strict=True):
            out[on] = new
    return first, tuple(at_h), tuple(at_s)


@dataclass(frozen=True)
class DesignRows:
    """The program's linear model at the design values, row by row (module docstring):
    system j's bins have the global columns ``X[j]`` (N, n_g) and the hold-local ones
    (``local_idx[j]``, ``local_val[j]``) (N, 4) among the n_b = 3H unknowns (o₁, o₂, δ per
    hold), and the variance ``var`` (N, 2) = ``base`` (σⱼ²/n) + ``trans2`` ((κ trans)²);
    ``prec_g`` (n_g,) and ``prec_b`` (n_b,) are the priors' precisions (Λ⁻¹);
    ``level_cols`` the global columns of the pendulums' horizontals Δm₀₁, Δm₀₂ (the last
    X-response column of each system, :mod:`chekan.joint.xresponse`), empty without X rounds."""

    layout: Layout
    sens: Sensitivities
    X: tuple[np.ndarray, np.ndarray]
    local_idx: tuple[np.ndarray, np.ndarray]
    local_val: tuple[np.ndarray, np.ndarray]
    base: np.ndarray
    trans2: np.ndarray
    prec_g: np.ndarray
    prec_b: np.ndarray
    level_cols: np.ndarray

    @property
    def var(self) -> np.ndarray:
        return self.base + self.trans2


def design_rows(program: TiltProgram, values: DesignValues | None = None) -> DesignRows:
    """The rows of the program's linear model: Xⱼ, the hold-local columns, the bins'
    variances and the priors (:class:`DesignRows`)."""
    values = values or DesignValues()
    truth = values.truth
    layout = program_layout(program, values)
    H = layout.theta_hold_rad.size
    tau = float(truth.tau_s)
    sens, (E_h, dE_h, S_h), (E_s, dE_s, S_s) = _hold_sensitivities(layout, truth)
    cols_h = np.concatenate([E_h[..., None], dE_h], axis=-1)  # (H, 2, 1 + 6)
    cols_s = np.concatenate([E_s[..., None], dE_s], axis=-1)  # (H, M, 2, 1 + 6)
    lag = lagged_means(layout, tau, cols_h, cols_s)
    h = 1e-4
    f_up = lagged_means(layout, tau * math.exp(h), cols_h[..., :1], cols_s[..., :1]).f[..., 0]
    f_dn = lagged_means(layout, tau * math.exp(-h), cols_h[..., :1], cols_s[..., :1]).f[..., 0]
    df_dlogtau = (f_up - f_dn) / (2.0 * h)
    noise = np.asarray(truth.noise_pix, dtype=float)
    base = noise[None, :] ** 2 / layout.bin_n[:, None]
    trans2 = (values.slew_error * lag.trans) ** 2
    s_ang = -S_h / ARCSEC_PER_RAD  # (H, 2) pix per arcsec of readout error

    B, B_path, B_var = systematic_basis(layout, values)
    Phi, Phi_path, Phi_var = x_response_columns(
        layout, truth, horizontal_prior(values.horizontal_u_pix)[0]
    )
    # the shared terms move the bins exactly as the equilibria they shift (f: the lag state
    # after each slew and the unsettled carry across holds), per system
    if B.shape[1]:
        sys_f = lagged_means(
            layout,
            tau,
            s_ang[:, :, None] * B[:, None, :],
            (-S_s / ARCSEC_PER_RAD)[..., None] * B_path[:, :, None, :],
        ).f  # (N, 2, Q)
    if Phi.shape[1]:
        x_f = lagged_means(
            layout,
            tau,
            np.broadcast_to(Phi[:, None, :], (H, 2, Phi.shape[1])),
            np.broadcast_to(Phi_path[:, :, None, :], (*Phi_path.shape[:2], 2, Phi.shape[1])),
        ).f  # (N, 2, X)
    n_old = 9 + 2 * (values.drift_degree if values.drift else 0)
    nx = Phi.shape[1]
    ng = n_old + B.shape[1] + 2 * nx
    Xs, idxs, vals = [], [], []
    for j in range(2):
        X = _global_columns(values, layout, lag.f[..., 1:], df_dlogtau, j)
        if B.shape[1]:  # ζ, ξ, η: angle errors, shared by both systems
            X = np.concatenate([X, sys_f[:, j, :]], axis=1)
        if nx:  # the X response beyond eq. (6), per system, settling in with the lag
            X_x = np.zeros((X.shape[0], 2 * nx))
            X_x[:, j * nx : (j + 1) * nx] = x_f[:, j, :]
            X = np.concatenate([X, X_x], axis=1)
        idx, val = _local_columns(values, layout, lag, s_ang, j)
        Xs.append(X)
        idxs.append(idx)
        vals.append(val)
    # priors (Λ⁻¹); switched-off random effects keep a unit precision: their columns are zero
    prec_g = np.zeros(ng)
    if values.priors:
        prec_g[:7] = [1.0 / p.scale**2 for p in nonlinear_params()]
        prec_g[7:9] = 1.0 / C_PRIOR_VAR_PIX2
        prec_g[9:n_old] = 1.0 / DRIFT_PRIOR_VAR_PIX2
    prec_g[n_old : n_old + B.shape[1]] = 1.0 / B_var  # Type B: the specification's prior
    prec_g[n_old + B.shape[1] :] = 1.0 / np.tile(Phi_var, 2)  # :mod:`chekan.joint.xresponse`
    if not values.estimate_tau:
        prec_g[6] = 1.0
    so2 = truth.hold_offset_sd_pix**2 if values.hold_offsets else 1.0
    st2 = truth.angle_error_sd_arcsec**2 if values.angle_errors else 1.0
    prec_b = np.tile([1.0 / so2, 1.0 / so2, 1.0 / st2], H)
    return DesignRows(
        layout, sens, (Xs[0], Xs[1]), (idxs[0], idxs[1]), (vals[0], vals[1]), base, trans2,
        prec_g, prec_b, np.array([ng - nx - 1, ng - 1]) if nx else np.zeros(0, dtype=int),
    )  # fmt: skip


def information_blocks(program: TiltProgram, values: DesignValues | None = None):
    """Prior-augmented expected information in blocks: M_gg (g = θ, c, d, ζ, ξ), M_gb and
    M_bb in upper banded storage (b = o₁, o₂, δ per hold), plus the layout, the
    sensitivities and the columns of the pendulums' horizontals (:class:`DesignRows`).

    M = Σⱼ Xⱼᵀ Wⱼ Xⱼ + Λ⁻¹ with the columns and weights of the module docstring.
    """
    rows = design_rows(program, values)
    ng, nb = rows.prec_g.size, rows.prec_b.size
    W = 1.0 / rows.var
    Mgg = np.zeros((ng, ng))
    Mgb = np.zeros((ng, nb))
    bb_pos, bb_w = [], []
    for j in range(2):
        X, idx, val = rows.X[j], rows.local_idx[j], rows.local_val[j]
        Wj = W[:, j]
        Mgg += X.T @ (X * Wj[:, None])
        wv = val * Wj[:, None]  # (N, 4)
        r_ = np.repeat(np.arange(idx.shape[0]), 4)
        L = scipy.sparse.csr_matrix((wv.ravel(), (r_, idx.ravel())), shape=(idx.shape[0], nb))
        Mgb += np.asarray((L.T @ X).T)  # Xᵀ Wⱼ L, duplicates summed
        r, c = idx[:, :, None], idx[:, None, :]
        upper = np.broadcast_to(r <= c, (idx.shape[0], 4, 4))
        pos = (_BAND + r - c) * nb + c
        bb_pos.append(pos[upper])
        bb_w.append((wv[:, :, None] * val[:, None, :])[upper])
    ab = np.bincount(
        np.concatenate(bb_pos), np.concatenate(bb_w), minlength=(_BAND + 1) * nb
    ).reshape(_BAND + 1, nb)
    Mgg += np.diag(rows.prec_g)
    ab[_BAND] += rows.prec_b
    return Mgg, Mgb, ab, rows.layout, rows.sens, rows.level_cols


def expected_precision(
    program: TiltProgram, values: DesignValues | None = None
) -> ExpectedPrecision:
    """Expected posterior sd of b₁, b₂, a, b₁,₀, b₂,₀ and θ for ``program`` (module doc):
    Σ_gg = (M_gg − M_gb M_bb⁻¹ M_bg)⁻¹, derived quantities by the delta method."""
    values = values or DesignValues()
    truth = values.truth
    Mgg, Mgb, ab, layout, sens, level_cols = information_blocks(program, values)
    Y = scipy.linalg.solveh_banded(ab, Mgb.T, lower=False, check_finite=False)
    cov = scipy.linalg.inv(Mgg - Mgb @ Y, check_finite=False)
    cov_tc = cov[:9, :9]  # (θ, c)
    sd = {name: math.sqrt(max(cov_tc[i, i], 0.0)) for i, name in enumerate(THETA_NAMES)}
    Jd = np.zeros((3, cov.shape[0]))  # ∇(a, b₁,₀, b₂,₀) over (θ, c, Δm₀); τ does not enter
    Jd[:, :6] = sens.derived_grad[:, :6]
    Jd[:, 7:9] = sens.derived_grad[:, 6:8]
    Jd[:, level_cols] = sens.derived_grad[:, 8 : 8 + level_cols.size]
    dvar = np.einsum("ij,jk,ik->i", Jd, cov, Jd)
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


def settled_transient(program: TiltProgram, values: DesignValues | None = None):
    """τ ↦ the largest transient (pix) that the sensor's lag leaves in a hold's settled
    mean: f − E of each hold's last bin (from the settling time on, what Calibr.exe
    averages; :func:`lagged_means` of the equilibria along holds and slews). The program
    is laid out and its equilibria computed once; only the lag depends on τ."""
    values = values or DesignValues()
    layout = program_layout(program, values)
    _, (E_h, _, _), (E_s, _, _) = _hold_sensitivities(layout, values.truth)
    E_h, E_s = np.asarray(E_h, dtype=float), np.asarray(E_s, dtype=float)
    last = np.array([np.flatnonzero(layout.bin_hold == k).max() for k in range(E_h.shape[0])])

    def largest(tau_s: float) -> float:
        lag = lagged_means(layout, tau_s, E_h[..., None], E_s[..., None])
        left = lag.f[last, :, 0] - E_h
        return float(np.max(np.abs(left[1:]), initial=0.0))  # hold 0: settled from the start

    return largest


def settled_transient_pix(program: TiltProgram, values: DesignValues | None = None) -> float:
    """:func:`settled_transient` at the design τ. Above
    :data:`chekan.classical.settling.UNSETTLED_PIX`
    the program's classical items are biased unless the transient is removed
    (:func:`chekan.results.document.settled_items`)."""
    values = values or DesignValues()
    return settled_transient(program, values)(float(values.truth.tau_s))


def settled_tau_limit_s(program: TiltProgram, values: DesignValues | None = None) -> float:
    """The longest lag τ (s) for which :func:`settled_transient` stays within
    :data:`chekan.classical.settling.UNSETTLED_PIX` (bisection in log τ on 1–1000 s; the transient
    grows with τ): the instruments whose classical items this program's settling serves."""
    from chekan.classical.settling import UNSETTLED_PIX

    left = settled_transient(program, values)
    lo, hi = 1.0, 1000.0
    if left(lo) > UNSETTLED_PIX:
        return 0.0
    if left(hi) <= UNSETTLED_PIX:
        return hi
    while hi / lo > 1.01:
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if left(mid) <= UNSETTLED_PIX else (lo, mid)
    return lo
