"""The quantities a calibration reports, derived from (θ, β): one function for map,
bayes and design.

    a = mean over systems of a(m_h) (eq. 10 at the level reading),
    bⱼ,₀ = b at the CCD centre (eq. 24), drift slope = Σₗ dⱼₗ (Pₗ(1) − Pₗ(−1)) / duration.

:func:`map_derived_fn` adds what the delta-method sds at the MAP need; :func:`draws_fn`
evaluates them for a posterior draw, with β drawn given θ. The engine compiles both
(:mod:`chekan.runtime.engine`); :mod:`chekan.fit.reported` runs them on a fit.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from chekan.joint.beta_posterior import bin_rows, dense_rows, posterior_cov, solve_beta
from chekan.joint.hold_blocks import apply_blocks, block_normal_equations
from chekan.joint.layout import ModelStructure, RecordData
from chekan.joint.likelihood import beta_prior_var, noise_var, sensor_params
from chekan.physics import sensor as fm
from chekan.physics.parameters import PHYSICAL
from inference.normal_eq import (
    banded_factor_blocks,
    draw_beta_factor,
    marginal_loglik_factor,
    split_prior,
)


def at_level(sp: fm.SensorParams):
    """(a, (b₁,₀, b₂,₀)) of sensor parameters: a = mean over systems of a(m_h) (eq. 10),
    bⱼ,₀ = b at the CCD centre (eq. 24). Shared by map, bayes and design."""
    return jnp.mean(fm.quadratic_coefficient(sp, sp.m_level_pix)), fm.scale_factor_at_centre(sp)


def at_horizontal(sp: fm.SensorParams, dm0_pix):
    """:func:`at_level` with each pendulum's horizontal at m₀ + Δm₀ⱼ (the level angle term of
    :mod:`chekan.joint.xresponse`): a(m_h) of eq. (10) is G''(φ_h)/(2K²), so it depends on
    where the horizontal is (≈ 14 ppm per pixel); b₀ stays at the CCD centre (eq. 24)."""
    a, b0 = fm.coefficients_at_horizontal(sp, dm0_pix)
    return jnp.mean(a), b0


def physical_quantities(v: dict, beta, structure: ModelStructure, data: RecordData, dur_h):
    """``PHYSICAL`` as named scalars at parameter values ``v`` and linear block ``beta``
    (also the level readings m_ref + c and the drift coefficients). A record about X
    carries each pendulum's horizontal Δm₀ⱼ in β (the X-response block's last column), and
    a is taken there (:func:`at_horizontal`)."""
    blocks = structure.beta_blocks
    D = structure.drift_degree
    ends = jnp.asarray([1.0 - (-1.0) ** ell for ell in range(1, D + 1)])  # P_l(1) − P_l(−1)
    sp = sensor_params(v, data, beta[blocks["c"]])
    if structure.n_x_response:
        dm0 = beta[blocks["x_response"]].reshape(2, structure.n_x_response)[:, -1]
        a, b0 = at_horizontal(sp, dm0)
    else:
        a, b0 = at_level(sp)
    dr = beta[blocks["drift"]].reshape(2, D)
    slope = dr @ ends / dur_h
    out = {
        "b1": v["b1"],
        "b2": v["b2"],
        "a": a,
        "b1_0": b0[0],
        "b2_0": b0[1],
        "eps1_arcmin": v["eps1_arcmin"],
        "eps2_arcmin": v["eps2_arcmin"],
        "dgamma_arcmin": v["dgamma_arcmin"],
        "tau_s": v["tau_s"],
        "drift1_pix_per_h": slope[0],
        "drift2_pix_per_h": slope[1],
    }
    return out, sp.m_level_pix, dr


def equilibria_of(sp: fm.SensorParams, tx, ty):
    """E and ∂E/∂θ (draws, K, 2) for parameters batched on their leading axis (the
    posterior predictive's hold equilibria, :mod:`chekan.fit.predictive`)."""
    E = jax.vmap(fm.equilibrium_readings, in_axes=(0, None, None))(sp, tx, ty)
    S = jax.vmap(fm.reading_sensitivity_to_tilt, in_axes=(0, None, None))(sp, tx, ty)
    return E, S


def map_derived_fn(structure: ModelStructure, space) -> Callable:
    """``(z, h, data, dur_h) → (g, ∂g/∂z total, ∂g/∂β, M⁻¹, β̂, Ã, base, transient, Λ)``,
    traceable; compiled once per structure by :class:`chekan.runtime.engine.Engine` (eager
    ``jacfwd`` would compile op by op in every new process, uncached). Ã (N, 2, p): the
    whitened design of β; base (N, 2): the bins' noise variance (sⱼσⱼ)²/n and transient
    (N, 2) the amplitude that κ scales, Λ (p,) β's prior variances: what
    :mod:`chekan.fit.typea` needs."""

    def core(z, h, data, dur_h):
        def g(z, beta):
            q, _, _ = physical_quantities(space.to_values(z), beta, structure, data, dur_h)
            return jnp.stack([q[n] for n in PHYSICAL])

        def beta_hat(z):
            return solve_beta(space.to_values(z), h, structure, data).beta

        sol = solve_beta(space.to_values(z), h, structure, data)
        beta, t = sol.beta, sol.terms
        Jz = jax.jacfwd(lambda zz: g(zz, beta_hat(zz)))(z)
        Jb = jax.jacfwd(lambda bb: g(z, bb))(beta)
        sw = jnp.where(data.mask, 1.0 / jnp.sqrt(t.nv), 0.0)
        A_w = dense_rows(bin_rows(t, structure, data), structure.n_beta) * sw[..., None]
        base = noise_var(h, data)
        trans = jnp.where(jnp.sum(data.own, axis=1)[:, None] > 0, t.trans, 0.0)  # 0: padding
        pv = beta_prior_var(h, structure, data)
        Minv = posterior_cov(sol.factor, structure)
        return g(z, beta), Jz, Jb, Minv, beta, A_w, base, trans, pv

    return core


def draws_fn(structure: ModelStructure, space) -> Callable:
    """``(z_bayes, key, data, duration h) →`` named draws of everything reported (β drawn
    given θ) and the point's log-density (``_logp``: the value of
    :meth:`chekan.joint.problem.CalibrationProblem.log_density`, from the same factor of M
    that draws β, so that a point is weighed and its quantities drawn in one evaluation),
    traceable; the record's duration is an argument, so records of one structure share the
    compiled function (:class:`chekan.runtime.engine.Engine`)."""
    blocks = structure.beta_blocks
    bands = structure.hold_bands

    def one(z, key, data: RecordData, dur_h):
        v = space.to_values(z)
        blocks_ne, t = block_normal_equations(v, v, structure, data)
        # block elimination of the holds' terms (as the log-density): N(M⁻¹g, M⁻¹) as before
        pv = split_prior(beta_prior_var(v, structure, data), bands)
        factor = banded_factor_blocks(blocks_ne, *pv)  # one factor: β's draw and the weight
        beta = draw_beta_factor(key, factor, bands, data.noise_order)
        lp = space.log_prior(z) + marginal_loglik_factor(blocks_ne, *pv, factor)
        # pointwise log-likelihood of each bin mean given this draw's (θ, β): conditional,
        # because the marginal over β does not factorise over bins
        r, nv = t.r, t.nv
        res_b = r - apply_blocks(beta, t, structure, data)
        loglik = jnp.where(data.mask, -0.5 * (res_b**2 / nv + jnp.log(2 * jnp.pi * nv)), 0.0)
        q, m_level, dr = physical_quantities(v, beta, structure, data, dur_h)
        delta = beta[blocks["angle_error"]]
        if structure.n_angle_cols:
            shared = np.concatenate([blocks["encoder"], blocks["angle_systematic"]])
            delta = delta + data.angle_basis @ beta[shared]
        sig = v["noise_scale"] * data.sigma_base
        return {
            **q,
            "sigma1_pix": sig[0],
            "sigma2_pix": sig[1],
            "sigma_theta_arcsec": v["sigma_theta_arcsec"],
            "sigma_hold_pix": v["sigma_hold_pix"],
            "slew_error": v["slew_error"],
            "m_level_pix": m_level,
            "drift_coeffs": dr,
            "angle_error_arcsec": delta,
            "hold_offset_pix": beta[blocks["hold_offset"]].reshape(2, -1).T,
            "_loglik": loglik,
            "_logp": jnp.where(jnp.isfinite(lp), lp, -jnp.inf),  # log p(θ, h | y), β marginal
        }

    def many(zs, keys, data, dur_h):
        # lax.map, not vmap: XLA on CPU compiles/executes batched factorisations of this size
        # pathologically slowly (batch 8: 9 ms; batch 16: minutes); a loop is fast and predictable
        return jax.lax.map(lambda zk: one(zk[0], zk[1], data, dur_h), (zs, keys))

    return many
