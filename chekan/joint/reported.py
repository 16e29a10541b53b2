"""The reported quantities of a fit, evaluated by the engine's compiled functions
(:mod:`chekan.runtime.engine`; their maths: :mod:`chekan.joint.derived`): at the MAP with
delta-method sds and the hyperparameters' Type A (:mod:`chekan.joint.typea`), and for every
posterior draw, with β drawn given θ."""

from __future__ import annotations

from typing import Any

import numpy as np

from chekan.jaxconfig import device_array
from chekan.joint.map import MapFit
from chekan.joint.typea import reliabilities
from chekan.physics.parameters import PHYSICAL
from chekan.runtime.engine import engine_for
from inference.chunks import map_chunks


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


def posterior_draws(fit: MapFit, zs: np.ndarray, keys, chunk: int = 256) -> dict:
    """Every reported quantity for each posterior draw ``zs`` (n, 12), β drawn given θ
    with ``keys``; in fixed-size chunks on both cores (one compile, bounded memory; the size:
    ``docs/tuning.md``)."""
    model = fit.model
    fn = engine_for(model.structure).draws
    dur_h = model.duration_h  # traced, as in map_derived
    return map_chunks(lambda z, k: fn(z, k, model.data, dur_h), [zs, keys], chunk)
