"""The quantities a calibration reports, derived from (θ, β): one function for map,
bayes and design.

    a = mean over systems of a(m_h) (eq. 10 at the level reading),
    bⱼ,₀ = b at the CCD centre (eq. 24), drift slope = Σₗ dⱼₗ (Pₗ(1) − Pₗ(−1)) / duration.

:func:`map_derived` adds delta-method sds at the MAP; :func:`posterior_draws` evaluates
them for every posterior draw, with β drawn given θ.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from chekan import model as fm
from chekan.jaxconfig import device_array
from chekan.joint.hold_blocks import apply_blocks, block_normal_equations
from chekan.joint.layout import ModelStructure, RecordData, RecordModel
from chekan.joint.likelihood import (
    beta_prior_var,
    dense_design,
    noise_var,
    sensor_params,
    solve_beta,
)
from chekan.joint.map import MapFit
from chekan.joint.typea import reliabilities
from chekan.parameters import PHYSICAL
from inference.chunks import map_chunks
from inference.normal_eq import draw_beta_blocks, split_prior


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


def map_derived_fn(structure: ModelStructure, space) -> Callable:
    """``(z, h, data, dur_h) → (g, ∂g/∂z total, ∂g/∂β, M⁻¹, β̂, Ã, base, transient, Λ)``,
    traceable; compiled once per structure by :class:`chekan.joint.engine.Engine` (eager
    ``jacfwd`` would compile op by op in every new process, uncached). Ã (N, 2, p): the
    whitened design of β; base (N, 2): the bins' noise variance (sⱼσⱼ)²/n and transient
    (N, 2) the amplitude that κ scales, Λ (p,) β's prior variances: what
    :mod:`chekan.joint.typea` needs."""

    def core(z, h, data, dur_h):
        def g(z, beta):
            q, _, _ = physical_quantities(space.to_values(z), beta, structure, data, dur_h)
            return jnp.stack([q[n] for n in PHYSICAL])

        def beta_hat(z):
            return solve_beta(space.to_values(z), h, structure, data)[1]

        v = space.to_values(z)
        _, beta, L, (_, G, s, _, _, nv, trans, P) = solve_beta(v, h, structure, data, True)
        Jz = jax.jacfwd(lambda zz: g(zz, beta_hat(zz)))(z)
        Jb = jax.jacfwd(lambda bb: g(z, bb))(beta)
        Linv = jax.scipy.linalg.solve_triangular(L, jnp.eye(L.shape[0]), lower=True)
        sw = jnp.where(data.mask, 1.0 / jnp.sqrt(nv), 0.0)
        A_w = dense_design(G, s, structure, data, P) * sw[..., None]
        base = noise_var(h, data)
        pv = beta_prior_var(h, structure, data)
        return g(z, beta), Jz, Jb, Linv.T @ Linv, beta, A_w, base, trans, pv

    return core


def prefetch(model: RecordModel) -> None:
    """Start loading the stored executable of :func:`map_derived` for this model's
    structure in the background."""
    from chekan.joint.engine import MAP_DERIVED, engine_for

    engine_for(model.structure).prefetch(MAP_DERIVED, model.data, model.duration_h)


def map_derived(fit: MapFit) -> dict:
    """Derived quantities at the MAP with delta-method sds: ``{name: (value, sd)}``.

    With θ ~ N(θ̂, C) and β | θ ~ N(β̂(θ), M⁻¹):
    var g = (∂g/∂θ + ∂g/∂β ∂β̂/∂θ) C (…)ᵀ + ∂g/∂β M⁻¹ (∂g/∂β)ᵀ + uₕ²,
    uₕ² the variance from the hyperparameters' estimation (:mod:`chekan.joint.typea`).
    Hyperparameters are reported at their EM values (sd None); ``_m_level`` holds the
    estimated level readings, ``_nu_eff`` and ``_u_hyper`` each quantity's effective
    degrees of freedom and uₕ (:mod:`chekan.joint.typea`).
    """
    model, res, h = fit.model, fit.result, fit.hyper
    data = model.data
    blocks = model.structure.beta_blocks
    from chekan.joint.engine import engine_for

    jitted = engine_for(model.structure).map_derived
    out_j = jitted(device_array(res.z), h, data, model.duration_h)
    val, Jz, Jb, Minv, beta, A_w, base, trans, pv = (np.asarray(x) for x in out_j)
    cov = np.asarray(res.cov_z)
    finite = np.isfinite(np.diag(cov))
    cz = np.where(np.isfinite(cov), cov, 0.0)
    var = np.einsum("ij,jk,ik->i", Jz, cz, Jz) + np.einsum("ij,jk,ik->i", Jb, Minv, Jb)
    rel = reliabilities(fit, Jz, Jb, Minv, A_w, base, trans, pv)
    u_hyper = np.array([r.u2_components for r in rel])
    sd = np.sqrt(np.maximum(var + u_hyper, 0.0))
    if not finite.all():
        sd = np.where(np.abs(Jz[:, ~finite]).sum(axis=1) > 0, np.inf, sd)
    out: dict[str, Any] = {n: (float(val[i]), float(sd[i])) for i, n in enumerate(PHYSICAL)}
    s = np.asarray(h["noise_scale"]) * np.asarray(data.sigma_base)
    out["sigma1_pix"] = (float(s[0]), None)
    out["sigma2_pix"] = (float(s[1]), None)
    out["sigma_theta_arcsec"] = (float(h["sigma_theta_arcsec"]), None)
    out["sigma_hold_pix"] = (float(h["sigma_hold_pix"]), None)
    out["slew_error"] = (float(h["slew_error"]), None)
    out["_m_level"] = np.asarray(data.m_ref) + np.asarray(beta)[blocks["c"]]
    out["_nu_eff"] = {n: rel[i].nu_eff for i, n in enumerate(PHYSICAL)}
    out["_type_a_clipped"] = any(r.clipped for r in rel)
    out["_u_hyper"] = {n: float(np.sqrt(max(u_hyper[i], 0.0))) for i, n in enumerate(PHYSICAL)}
    return out


def draws_fn(structure: ModelStructure, space) -> Callable:
    """``(z_bayes, key, data, duration h) →`` named draws of everything reported (β drawn
    given θ), traceable; the record's duration is an argument, so records of one structure
    share the compiled function (:class:`chekan.joint.engine.Engine`)."""
    blocks = structure.beta_blocks
    bands = structure.hold_bands

    def one(z, key, data: RecordData, dur_h):
        v = space.to_values(z)
        blocks_ne, t = block_normal_equations(v, v, structure, data)
        # block elimination of the holds' terms (as the log-density): N(M⁻¹g, M⁻¹) as before
        pv = split_prior(beta_prior_var(v, structure, data), bands)
        beta = draw_beta_blocks(key, blocks_ne, *pv, bands)
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
        }

    def many(zs, keys, data, dur_h):
        # lax.map, not vmap: XLA on CPU compiles/executes batched factorisations of this size
        # pathologically slowly (batch 8: 9 ms; batch 16: minutes); a loop is fast and predictable
        return jax.lax.map(lambda zk: one(zk[0], zk[1], data, dur_h), (zs, keys))

    return many


def posterior_draws(fit: MapFit, zs: np.ndarray, keys, chunk: int = 256) -> dict:
    """Every reported quantity for each posterior draw ``zs`` (n, 12), β drawn given θ
    with ``keys``; in fixed-size chunks on both cores (one compile, bounded memory; the size:
    ``docs/tuning.md``)."""
    model = fit.model
    from chekan.joint.engine import engine_for

    fn = engine_for(model.structure).draws
    dur_h = model.duration_h  # traced, as in map_derived
    return map_chunks(lambda z, k: fn(z, k, model.data, dur_h), [zs, keys], chunk)
