"""What happens between two MAP passes, in one compiled function: the level reference
moves to its estimate, then the EM updates of the hyperparameters run to their fixed
point at fixed θ (a ``lax.while_loop``; the noise M-step a projected Newton,
:func:`inference.box_newton.minimise_in_box`). After ``EM_UPDATES_BEFORE_NEWTON`` updates
without convergence the fixed point h = EM(h) is solved for by optimistix's Newton in log h
(EM creeps where a variance sits at its bound). Measurements: ``docs/tuning.md``.

Every function returns new state; nothing it is handed is changed.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from chekan.jaxconfig import device_array
from chekan.joint.em import (
    HYPER_MAX_UPDATES,
    HYPER_TOL,
    K_LOC,
    K_SD,
    NOISE_LOWER,
    NOISE_UPPER,
    S_LOC,
    S_SD,
    SIGMA_HOLD_BOUNDS_PIX,
    SIGMA_THETA_BOUNDS_ARCSEC,
    beta_moments,
)
from chekan.joint.layout import ModelStructure, RecordData, RecordModel
from chekan.joint.likelihood import solve_beta
from chekan.joint.problem import Hyper
from inference.box_newton import minimise_in_box
from inference.jacobian import jacobian_once

EM_UPDATES_BEFORE_NEWTON = 32  # then Newton on the fixed point (docs/tuning.md)
NEWTON_TOL = 1e-8  # on the Newton step and on EM(h) − h, in log h
NEWTON_MAX_STEPS = 32
_HYPER_KEYS = ("noise_scale", "sigma_theta_arcsec", "sigma_hold_pix", "slew_error")


def between_passes(model: RecordModel, z, h: Hyper) -> tuple[RecordModel, Hyper, int]:
    """:func:`chekan.joint.em.between_passes` compiled: the model with its level moved to
    the estimate (m_ref ← m_ref + ĉ), the hyperparameters at their EM fixed point given θ = z,
    and the number of EM updates."""
    from chekan.joint.engine import engine_for

    em_pass = engine_for(model.structure).em_pass
    m_ref, h_new, n = em_pass(device_array(z), h, model.data)
    return model.with_level(np.asarray(m_ref)), h_new, int(n)


def prefetch(model: RecordModel) -> None:
    """Start loading this structure's stored EM pass in the background."""
    from chekan.joint.engine import EM_PASS, engine_for

    engine_for(model.structure).prefetch(EM_PASS, model.data)


def em_pass_fn(structure: ModelStructure, space) -> Callable:
    """``(z, h, data) → (m_ref, h, updates)``: the level moved to its estimate, then EM to
    its fixed point (Newton after ``EM_UPDATES_BEFORE_NEWTON``), traceable; compiled by
    :class:`chekan.joint.engine.Engine`."""

    def fn(z, h: Hyper, data: RecordData):
        v = space.to_values(z)
        _, beta, _ = solve_beta(v, h, structure, data)
        m_ref = data.m_ref + beta[structure.beta_blocks["c"]]
        data = dataclasses.replace(data, m_ref=m_ref)

        def em_until(limit):
            def cond(c):
                _, n, change = c
                return (change >= HYPER_TOL) & (n < limit)

            return cond

        def body(c):
            h, n, _ = c
            new = em_update(v, h, structure, data)
            change = jnp.max(
                jnp.stack([jnp.max(jnp.abs(jnp.log(new[k]) - jnp.log(h[k]))) for k in h])
            )
            return new, n + 1, change

        c = jax.lax.while_loop(em_until(EM_UPDATES_BEFORE_NEWTON), body, (h, 0, jnp.inf))
        newton = functools.partial(_newton, v, structure, data)
        c = jax.lax.cond(c[2] >= HYPER_TOL, newton, lambda c: c, c)
        h, n, _ = jax.lax.while_loop(em_until(HYPER_MAX_UPDATES), body, c)
        return m_ref, h, n

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


def _newton(v: dict, structure: ModelStructure, data: RecordData, carry):
    """The EM fixed point h = EM(h) by optimistix's Newton in log h, from the EM iterate
    in ``carry`` = (h, updates, change); the carry unchanged where Newton fails (EM then
    goes on), else (h*, updates + Newton steps, 0)."""
    import optimistix as optx  # at trace time only: stored executables do not need it

    h, n, change = carry

    def em_map(x, args):
        v_, data_ = args
        return _log_hyper(em_update(v_, _hyper(x), structure, data_))

    solver: optx.Newton = optx.Newton(rtol=NEWTON_TOL, atol=NEWTON_TOL)
    sol: optx.Solution = optx.fixed_point(
        jacobian_once(em_map),  # one copy of the EM map's tangent code, not two
        solver,
        _log_hyper(h),
        (v, data),
        max_steps=NEWTON_MAX_STEPS,
        throw=False,
    )
    ok = (sol.result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(sol.value))
    x = jnp.where(ok, sol.value, _log_hyper(h))
    steps = sol.stats["num_steps"]
    return _hyper(x), jnp.where(ok, n + steps, n), jnp.where(ok, 0.0, change)


def em_update(v: dict, h: Hyper, structure: ModelStructure, data: RecordData) -> Hyper:
    """One EM update at θ (values ``v``), traceable: :func:`chekan.joint.em.em_update`.

    σ_o² = mean(ô² + var o) and σ_θ² = mean(δ̂² + var δ) over the real holds, with the
    conditional variances of β from M⁻¹; (s₁, s₂, κ) from the expected squared residuals
    r̂² + leverage (:func:`noise_m_step`)."""
    rw, beta, var, base, trans, lev = beta_moments(v, h, structure, data)
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
    the box of :func:`chekan.joint.em.noise_m_step` (traceable; started at ``x0`` =
    (log s₁, log s₂, log κ))."""
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
