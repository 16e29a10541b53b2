"""The EM of the hyperparameters between two MAP passes, in one compiled function.

The level reference moves to its estimate (m_ref ← m_ref + ĉ), then EM updates of the
hyperparameters run to their fixed point at θ̂ (a ``lax.while_loop``; the noise
M-step a projected Newton, :func:`inference.box_newton.minimise_in_box`).

**The E-step integrates θ as well as β** (the REML analogue). Its moments are
those of the joint Laplace posterior of (θ, β) at θ̂, not of β given θ = θ̂: with
β̂(θ) ≈ β̂ + B(θ − θ̂), B = ∂β̂/∂θ, and θ ~ N(θ̂, C_θ),

    E[ββᵀ] = β̂β̂ᵀ + M⁻¹ + B C_θ Bᵀ,    E[rᵢ²] = r̂ᵢ² + (Ã M⁻¹ Ãᵀ)ᵢᵢ + (J_r C_θ J_rᵀ)ᵢᵢ,

J the Jacobian of the MAP's stacked residual [r_w, β̂/√Λ, θ's prior rows] in θ (its bin
rows J_r), C_θ = (JᵀJ)⁻¹, all at the current hyperparameters
(:func:`chekan.joint.em_theta.theta_part`, from the derivatives of f, A and the transient
in θ, which do not depend on h and are formed once per EM stage by
:func:`~chekan.joint.em_theta.design_derivatives`, as are the bins' terms at θ,
:func:`chekan.joint.hold_blocks.bin_design`; the rest is linear algebra). Every
moment comes from M's hold blocks (:func:`chekan.joint.beta_posterior.block_moments`: β̂,
diag(M⁻¹) and the leverages from the entries of M⁻¹ on M's pattern; A and ∂A/∂θ by the
support of their rows), so an update is O(N·(6 + m)·q), never O(p³) (``docs/tuning.md``).
Maximising over θ instead (these terms left out) is ML for the
variance components, biased low by the degrees of freedom that θ takes: on 200 simulated
3 h sessions without systematic angle errors the EM's σ_θ² was 0.91 and σ_o² 0.91 of the
truth (0.93, 0.91 on 9 h) and the MAP's mean z² of b 1.18 where the true hyperparameters
give 0.98–1.00; with these terms σ_θ² 0.97, σ_o² 1.00 and z² 1.07
(``docs/figures/validation_type_a.md``).

After ``EM_UPDATES_BEFORE_NEWTON`` updates without convergence the fixed point h = EM(h) is
solved for by optimistix's Newton in log h (EM creeps where a variance sits at its bound);
where Newton fails (a fixed point on a clip bound) EM goes on accelerated by SQUAREM
(:func:`inference.squarem.squarem`) up to ``HYPER_MAX_UPDATES``. Both MAP solvers use it
(``map_solver`` only chooses the passes' solver). Measurements: ``docs/tuning.md``.

Every function returns new state; nothing it is handed is changed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from chekan.joint.beta_posterior import beta_mean
from chekan.joint.em_theta import Design, design_derivatives, moments, theta_part
from chekan.joint.em_theta import theta_terms as theta_terms  # re-exported (tests, docs)
from chekan.joint.hold_blocks import BinDesign, bin_design
from chekan.joint.layout import ModelStructure, RecordData
from chekan.joint.problem import Hyper, hyper_params
from inference.box_newton import minimise_in_box
from inference.jacobian import jacobian_once
from inference.squarem import squarem

HYPER_TOL = 1e-4  # EM stops when no log-hyperparameter moves more than this in an update
HYPER_MAX_UPDATES = 200  # EM updates between two passes at most (Newton's steps counted)
EM_UPDATES_BEFORE_NEWTON = 32  # then Newton on the fixed point (docs/tuning.md)
NEWTON_TOL = 1e-8  # on the Newton step and on EM(h) − h, in log h
NEWTON_MAX_STEPS = 32
# the noise M-step: box of (log s₁, log s₂, log κ) and the priors of log s and log κ,
# read from the sampled hyperparameters' definitions (chekan.joint.problem.hyper_params)
NOISE_LOWER = np.log([0.05, 0.05, 1e-5])
NOISE_UPPER = np.log([50.0, 50.0, 0.5])
_PRIOR = {p.name: p for p in hyper_params()}
S_LOC, S_SD = _PRIOR["noise_scale"].loc, _PRIOR["noise_scale"].scale
K_LOC, K_SD = _PRIOR["slew_error"].loc, _PRIOR["slew_error"].scale
# where the EM clips σ_θ (arcsec) and σ_o (pix): inside the range a record can inform
SIGMA_THETA_BOUNDS_ARCSEC = (0.05, 30.0)
SIGMA_HOLD_BOUNDS_PIX = (1e-3, 5.0)
#: the box of :func:`_log_hyper` (log s₁, log s₂, log σ_θ, log σ_o, log κ) that EM maps into
LOG_LOWER = np.r_[
    NOISE_LOWER[:2],
    np.log([SIGMA_THETA_BOUNDS_ARCSEC[0], SIGMA_HOLD_BOUNDS_PIX[0]]),
    NOISE_LOWER[2],
]
LOG_UPPER = np.r_[
    NOISE_UPPER[:2],
    np.log([SIGMA_THETA_BOUNDS_ARCSEC[1], SIGMA_HOLD_BOUNDS_PIX[1]]),
    NOISE_UPPER[2],
]
AT_BOUND_LOG = 1e-3  # a hyperparameter within this (in log) of an EM bound is "at the bound"
_HYPER_KEYS = ("noise_scale", "sigma_theta_arcsec", "sigma_hold_pix", "slew_error")


HYPER_NAMES = ("noise scale s₁", "noise scale s₂", "σ_θ", "σ_o", "slew error κ")  # _log_hyper's


def still_moving(step) -> tuple[tuple[str, float], ...]:
    """The log-hyperparameters that an EM update still moves by ``HYPER_TOL`` or more, with
    their move (``step`` from :func:`em_newton_fn`'s output, in :data:`HYPER_NAMES` order)."""
    d = np.asarray(step, dtype=float).reshape(-1)
    return tuple((n, float(v)) for n, v in zip(HYPER_NAMES, d, strict=True) if abs(v) >= HYPER_TOL)


def to_zero(moving: tuple[tuple[str, float], ...]) -> bool:
    """Whether an EM that stopped at its cap was creeping down to a variance of zero: every
    hyperparameter that still moves falls (EM converges slowly to a boundary, where the data
    show none of that variance; its clip bound stops it there). Anything else still moving
    (rising, or a scale of the noise) is an EM that has not converged."""
    return bool(moving) and all(v < 0.0 and not n.startswith("noise") for n, v in moving)


def _em_body(update: Callable, data: RecordData):
    """One EM update of the loop's carry (h, updates, largest change in log h)."""

    def body(c):
        h, n, _ = c
        new = update(h, data)
        change = jnp.max(jnp.stack([jnp.max(jnp.abs(jnp.log(new[k]) - jnp.log(h[k]))) for k in h]))
        return new, n + 1, change

    return body


def _em_until(limit: int) -> Callable:
    """The loop's condition: not converged and fewer than ``limit`` updates."""

    def cond(c):
        _, n, change = c
        return (change >= HYPER_TOL) & (n < limit)

    return cond


def _em_stage(z, structure: ModelStructure, data: RecordData, space) -> Callable:
    """The EM update at θ = z with θ integrated in the E-step (:func:`theta_terms`),
    traceable. What depends on θ alone is formed here, once, not in every update: the bins'
    terms (equilibria, slews, lag weights: :func:`~chekan.joint.hold_blocks.bin_design`) and
    their derivatives in θ (:class:`Design`)."""
    v = space.to_values(z)
    at = bin_design(v, structure, data)
    design = design_derivatives(z, structure, data, space)

    def update(h, data_, frozen_theta=False):
        return em_update(v, h, structure, data_, design, frozen_theta, at)

    return update


def em_pass_fn(structure: ModelStructure, space) -> Callable:
    """``(z, h, data) → (m_ref, h, updates, change)``: the level moved to its estimate, then
    up to ``EM_UPDATES_BEFORE_NEWTON`` EM updates with θ integrated in the E-step
    (``change``: the last update's largest move in log h; at least ``HYPER_TOL`` where EM
    has not converged), traceable; compiled by :class:`chekan.runtime.engine.Engine`."""

    def fn(z, h: Hyper, data: RecordData):
        beta = beta_mean(space.to_values(z), h, structure, data).beta
        m_ref = data.m_ref + beta[structure.beta_blocks["c"]]
        data = dataclasses.replace(data, m_ref=m_ref)
        update = _em_stage(z, structure, data, space)
        c = (h, jnp.asarray(0), jnp.asarray(jnp.inf))
        h, n, change = jax.lax.while_loop(
            _em_until(EM_UPDATES_BEFORE_NEWTON), _em_body(update, data), c
        )
        return m_ref, h, n, change

    return fn


def em_newton_fn(structure: ModelStructure, space) -> Callable:
    """``(z, h, updates, change, data) → (h, updates, change, step)``: where
    :func:`em_pass_fn` stopped unconverged (``data`` with the level already moved), the fixed
    point by Newton (:func:`_newton`); where Newton fails (a fixed point on a clip bound, which
    EM only creeps towards), EM accelerated by SQUAREM (:func:`inference.squarem.squarem`)
    to convergence or ``HYPER_MAX_UPDATES`` updates (``change`` ≥ ``HYPER_TOL`` then);
    ``step``: the next update's move of each log-hyperparameter (:data:`HYPER_NAMES`), which
    names what still moves (:func:`still_moving`), traceable."""

    def fn(z, h: Hyper, n, change, data: RecordData):
        update = _em_stage(z, structure, data, space)
        h, n, change = _newton(update, data, (h, n, change))
        sol = squarem(
            lambda x: _log_hyper(update(_hyper(x), data)),
            _log_hyper(h),
            jnp.asarray(LOG_LOWER),
            jnp.asarray(LOG_UPPER),
            tol=HYPER_TOL,
            max_updates=HYPER_MAX_UPDATES,
            num_updates=n,
            change=change,
        )
        h = _hyper(sol.x)
        return h, sol.num_updates, sol.change, _log_hyper(update(h, data)) - _log_hyper(h)

    return fn


def _log_hyper(h: Hyper) -> jax.Array:
    return jnp.concatenate([jnp.log(jnp.atleast_1d(h[k])) for k in _HYPER_KEYS])


def _hyper(x: jax.Array) -> Hyper:
    """:func:`_log_hyper` inverted (noise_scale (2,), then the three scalars)."""
    return {
        "noise_scale": jnp.exp(x[:2]),
        "sigma_theta_arcsec": jnp.exp(x[2]),
        "sigma_hold_pix": jnp.exp(x[3]),
        "slew_error": jnp.exp(x[4]),
    }


def _newton(update: Callable, data: RecordData, carry):
    """The EM fixed point h = ``update``(h, data) by optimistix's Newton in log h, from the
    EM iterate in ``carry`` = (h, updates, change); the carry unchanged where Newton fails
    (EM then goes on), else (h*, updates + Newton steps, 0). Newton's Jacobian leaves out
    how θ's terms of the E-step move with h (``stop_gradient``: a few per cent of the
    moments, and a second derivative of the solve); the fixed point is the exact one."""
    import optimistix as optx  # at trace time only: stored executables do not need it

    h, n, change = carry

    def em_map(x, data_):
        return _log_hyper(update(_hyper(x), data_, frozen_theta=True))

    solver: optx.Newton = optx.Newton(rtol=NEWTON_TOL, atol=NEWTON_TOL)
    sol: optx.Solution = optx.fixed_point(
        jacobian_once(em_map),  # one copy of the EM map's tangent code, not two
        solver,
        _log_hyper(h),
        data,
        max_steps=NEWTON_MAX_STEPS,
        throw=False,
    )
    ok = (sol.result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(sol.value))
    x = jnp.where(ok, sol.value, _log_hyper(h))
    steps = sol.stats["num_steps"]
    return _hyper(x), jnp.where(ok, n + steps, n), jnp.where(ok, 0.0, change)


def em_update_theta(z, h: Hyper, data: RecordData, *, space, structure: ModelStructure) -> Hyper:
    """One EM update at θ = z (working units) whose E-step integrates θ, traceable (as the
    EM between passes runs it, with :class:`Design` formed here)."""
    d = design_derivatives(z, structure, data, space)
    return em_update(space.to_values(z), h, structure, data, d)


def em_update(
    v: dict,
    h: Hyper,
    structure: ModelStructure,
    data: RecordData,
    design: Design | None = None,
    frozen_theta: bool = False,
    at: BinDesign | None = None,
) -> Hyper:
    """One EM update of the hyperparameters at θ (values ``v``), real holds and bins only,
    traceable.

    σ_o² = mean(ô² + var o) and σ_θ² = mean(δ̂² + var δ) over the real holds, with the
    variances of β from M⁻¹; (s₁, s₂, κ) from the expected squared residuals r̂² + leverage
    (:func:`noise_m_step`). With ``design`` (:func:`design_derivatives` at this θ) the
    E-step integrates θ: :func:`~chekan.joint.em_theta.theta_part` added to those variances
    and leverages (``frozen_theta``: without their derivative in h, for Newton's Jacobian);
    None: θ known (ML). ``at``: the bins' terms at θ
    (:func:`~chekan.joint.hold_blocks.bin_design`) if already computed."""
    m = moments(v, h, structure, data, at)
    rw, beta, base, trans, lev = m.rw, m.beta, m.base, m.trans, m.lev
    var = m.var
    if design is not None:
        extra = theta_part(design, m, h, structure, data)
        if frozen_theta:
            extra = jax.lax.stop_gradient(extra)
        var = var + extra[0]
        lev = lev + extra[1]
    blocks = structure.beta_blocks
    hold = data.hold_mask.astype(beta.dtype)

    def mean_square(ix, w):
        return jnp.sum(w * (beta[ix] ** 2 + var[ix])) / jnp.sum(w)

    nv = base + (h["slew_error"] * trans) ** 2
    e2 = jnp.where(data.mask, (rw.reshape(data.mask.shape) ** 2 + lev) * nv, 0.0)
    x0 = jnp.concatenate([jnp.log(h["noise_scale"]), jnp.log(h["slew_error"])[None]])
    scale, kappa = noise_m_step(e2, base / h["noise_scale"][None, :] ** 2, trans, data.mask, x0)
    return {
        "noise_scale": scale,
        "sigma_theta_arcsec": jnp.clip(
            jnp.sqrt(mean_square(blocks["angle_error"], hold)), *SIGMA_THETA_BOUNDS_ARCSEC
        ),
        "sigma_hold_pix": jnp.clip(
            jnp.sqrt(mean_square(blocks["hold_offset"], jnp.tile(hold, 2))),
            *SIGMA_HOLD_BOUNDS_PIX,
        ),
        "slew_error": kappa,
    }


def noise_m_step(e2, b0, trans, mask, x0) -> tuple[jax.Array, jax.Array]:
    """(s₁, s₂, κ) minimising Σ ½(log v + E[e²]/v) + log-priors, v = sⱼ² b₀ + κ² t², inside
    the box ``NOISE_LOWER``…``NOISE_UPPER`` (traceable; started at ``x0`` = (log s₁, log s₂,
    log κ)). Settled bins (t = 0) fix sⱼ, the settling ones then fix κ; priors of log s and
    log κ from :func:`chekan.joint.problem.hyper_params`."""
    m = mask.astype(e2.dtype)
    t2 = trans**2

    def f(x):
        ls, lk = x[:2], x[2]
        v = jnp.exp(2 * ls)[None, :] * b0 + jnp.exp(2 * lk) * t2
        v = jnp.where(mask, v, 1.0)
        val = 0.5 * jnp.sum(m * (jnp.log(v) + e2 / v))
        prior = 0.5 * jnp.sum(((ls - S_LOC) / S_SD) ** 2) + 0.5 * ((lk - K_LOC) / K_SD) ** 2
        return val + prior

    x = minimise_in_box(f, x0, jnp.asarray(NOISE_LOWER), jnp.asarray(NOISE_UPPER)).x
    return jnp.exp(x[:2]), jnp.exp(x[2])


def beta_moments(v: dict, h: Hyper, structure: ModelStructure, data: RecordData):
    """Traceable: the whitened residuals, β̂ and its conditional variances diag(M⁻¹), the
    base noise variance, the transient amplitudes and the bins' leverages at θ (values
    ``v``): what an EM update needs."""
    m = moments(v, h, structure, data)
    return m.rw.reshape(-1), m.beta, m.var, m.base, m.trans, m.lev
