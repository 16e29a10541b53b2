"""What happens between two passes of the MAP: the level reference moves to its
estimate and the hyperparameters go to their EM fixed point at fixed θ.

Every function returns new state; nothing it is handed is changed.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from chekan.jaxconfig import device_array
from chekan.joint.layout import ModelStructure, RecordData, RecordModel
from chekan.joint.likelihood import dense_design, noise_var, solve_beta
from chekan.joint.problem import Hyper, default_hyper, hyper_params

HYPER_TOL = 1e-4  # EM at fixed θ stops when no log-hyperparameter moves more than this
HYPER_MAX_UPDATES = 200  # ~8 ms each on a 9 h record
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
AT_BOUND_LOG = 1e-3  # a hyperparameter within this (in log) of an EM bound is "at the bound"


def hyper_at_bounds(h: Hyper) -> list[str]:
    """The hyperparameters that the EM left at one of its clip bounds, in words: there the
    data did not determine them, and the uncertainty that rests on them may be wrong."""
    s = np.asarray(h["noise_scale"], dtype=float).reshape(-1)
    values = [
        ("noise scale s₁", float(s[0]), np.exp(NOISE_LOWER[0]), np.exp(NOISE_UPPER[0]), ""),
        ("noise scale s₂", float(s[1]), np.exp(NOISE_LOWER[1]), np.exp(NOISE_UPPER[1]), ""),
        (
            "slew error κ",
            float(h["slew_error"]),
            np.exp(NOISE_LOWER[2]),
            np.exp(NOISE_UPPER[2]),
            "",
        ),
        ("σ_θ", float(h["sigma_theta_arcsec"]), *SIGMA_THETA_BOUNDS_ARCSEC, "″"),
        ("σ_o", float(h["sigma_hold_pix"]), *SIGMA_HOLD_BOUNDS_PIX, " pix"),
    ]
    out = []
    for name, v, low, high, unit in values:
        for edge, which in ((low, "lower"), (high, "upper")):
            if abs(np.log(v) - np.log(edge)) < AT_BOUND_LOG:
                out.append(f"hyperparameter {name} = {v:.4g}{unit} ended at its {which} bound")
    return out


def between_passes(model: RecordModel, z, h: Hyper) -> tuple[RecordModel, Hyper, int]:
    """What follows every MAP pass but the last: :func:`recentre_level`, then
    :func:`converge_hyper`. Returns the model with its moved level, the new
    hyperparameters and the number of EM updates."""
    model, _ = recentre_level(model, z, h)
    h, n = converge_hyper(model, z, h)
    return model, h, n


def recentre_level(model: RecordModel, z, h: Hyper) -> tuple[RecordModel, np.ndarray]:
    """The model with its level reference moved to the estimate, m_ref ← m_ref + ĉ, and ĉ
    (pix).

    The equilibrium Eₖ is computed about m_ref (its position φ_h = (m_ref − m₀)/K on the
    torsion characteristic, and b is dG/dm there), while c only shifts the readings. The
    classical m_h that m_ref starts from is biased when the level holds have not settled
    (slow damping, short dwells: 17 pix at τ = 90 s on the 3 h program), and an additive
    shift does not move the curvature with it: that bias went into b (≈ +0.5 sd). After
    one pass ĉ is known to ~0.01 pix, so the next pass evaluates Eₖ about the estimated
    level itself.
    """
    _, beta, *_ = beta_at(model.structure, z, h, model.data)
    c = np.asarray(beta)[model.structure.beta_blocks["c"]]
    return model.with_level(np.asarray(model.data.m_ref) + c), c


def converge_hyper(model: RecordModel, z, h: Hyper) -> tuple[Hyper, int]:
    """EM updates (:func:`em_update`) at fixed θ = z until no log-hyperparameter moves by
    more than ``HYPER_TOL``: the hyperparameters of largest marginal likelihood given θ.
    Returns them and the number of updates made."""
    n, change = 0, np.inf
    while change >= HYPER_TOL and n < HYPER_MAX_UPDATES:
        new = em_update(model, z, h)
        change = max(float(np.max(np.abs(np.log(new[k]) - np.log(h[k])))) for k in h)
        h, n = new, n + 1
    return h, n


def em_update(model: RecordModel, z, h: Hyper) -> Hyper:
    """One EM update of the hyperparameters at θ = z (real holds and bins only):
    σ_o² = mean(ô² + var o), σ_θ² = mean(δ̂² + var δ) with the conditional variances of β
    from M⁻¹, and (s₁, s₂, κ) from the expected squared residuals r̂² + leverage."""
    data = model.data
    blocks = model.structure.beta_blocks
    mask = np.asarray(data.mask)
    hold = np.asarray(data.hold_mask)
    rw, beta, var, base, trans, lev = beta_at(model.structure, z, h, data)
    o_sel = blocks["hold_offset"][np.tile(hold, 2)]
    d_sel = blocks["angle_error"][hold]
    o, vo = beta[o_sel], var[o_sel]
    d, vd = beta[d_sel], var[d_sel]
    r = rw.reshape(mask.shape)
    nv = base + (float(h["slew_error"]) * trans) ** 2
    e2 = np.where(mask, (r**2 + lev) * nv, 0.0)  # E[squared residual | y] in pix²
    scale, kappa = noise_m_step(e2, base / np.asarray(h["noise_scale"])[None, :] ** 2, trans, mask)
    return default_hyper(
        noise_scale=scale,
        sigma_theta_arcsec=float(np.clip(np.sqrt(np.mean(d**2 + vd)), *SIGMA_THETA_BOUNDS_ARCSEC)),
        sigma_hold_pix=float(np.clip(np.sqrt(np.mean(o**2 + vo)), *SIGMA_HOLD_BOUNDS_PIX)),
        slew_error=kappa,
    )


def noise_m_step(e2, b0, trans, mask) -> tuple[np.ndarray, float]:
    """(s₁, s₂, κ) maximising Σ −½(log v + E[e²]/v) + log-priors, v = sⱼ² b₀ + κ² t².

    All bins at once: settled bins (t = 0) fix sⱼ, the settling ones then fix κ. Priors
    of log s and log κ from :func:`chekan.joint.problem.hyper_params`.
    """
    from scipy.optimize import minimize

    m = mask.astype(float)
    t2 = trans**2

    def f(x):
        ls, lk = x[:2], x[2]
        v = np.exp(2 * ls)[None, :] * b0 + np.exp(2 * lk) * t2
        v = np.where(mask, v, 1.0)
        q = m * (1.0 / v - e2 / v**2)  # ∂(log v + e²/v)/∂v
        val = 0.5 * np.sum(m * (np.log(v) + e2 / v))
        val += 0.5 * np.sum(((ls - S_LOC) / S_SD) ** 2) + 0.5 * ((lk - K_LOC) / K_SD) ** 2
        g_s = np.sum(q * np.exp(2 * ls)[None, :] * b0, axis=0) + (ls - S_LOC) / S_SD**2
        g_k = np.sum(q * np.exp(2 * lk) * t2) + (lk - K_LOC) / K_SD**2
        return val, np.concatenate([g_s, [g_k]])

    x0 = np.array([S_LOC, S_LOC, K_LOC])
    bounds = list(zip(NOISE_LOWER, NOISE_UPPER, strict=True))
    res = minimize(f, x0, jac=True, method="L-BFGS-B", bounds=bounds)
    return np.exp(res.x[:2]), float(np.exp(res.x[2]))


def beta_moments(v: dict, h: Hyper, structure: ModelStructure, data: RecordData):
    """Traceable: the whitened residuals, β̂ and its conditional variances diag(M⁻¹), the
    base noise variance, the transient amplitudes and the bins' leverages at θ (values
    ``v``): what an EM update needs (here on the host, compiled in
    :mod:`chekan.joint.em_compiled`)."""
    rw, beta, L, (_, G, s, _, _, nv, trans, P) = solve_beta(v, h, structure, data, extras=True)
    Linv = jax.scipy.linalg.solve_triangular(L, jnp.eye(L.shape[0]), lower=True)
    # leverage of each bin: (Ã M⁻¹ Ãᵀ)ᵢᵢ with Ã the whitened design (E[r²] = r̂² + lev)
    A = dense_design(G, s, structure, data, P)  # (N, 2, p)
    sw = jnp.where(data.mask, 1.0 / jnp.sqrt(nv), 0.0)
    X = jnp.einsum("qp,njp->njq", Linv, A * sw[..., None])
    lev = jnp.sum(X**2, axis=-1)
    return rw, beta, jnp.sum(Linv**2, axis=0), noise_var(h, data), trans, lev


def beta_moments_fn(structure: ModelStructure, space) -> Callable:
    """``(z, h, data) →`` :func:`beta_moments` at θ = z, traceable; compiled by
    :class:`chekan.joint.engine.Engine`."""

    def fn(z, h, data: RecordData):
        return beta_moments(space.to_values(z), h, structure, data)

    return fn


def prefetch(model: RecordModel) -> None:
    """Start loading the stored β̂ executable of this model's structure in the background."""
    from chekan.joint.engine import BETA_AT, engine_for

    engine_for(model.structure).prefetch(BETA_AT, model.data)


def beta_at(structure: ModelStructure, z, h: Hyper, data: RecordData):
    """β̂, its conditional variances diag(M⁻¹), the whitened residuals, the base noise
    variance, the transient amplitudes and the bins' leverages at θ = z."""
    from chekan.joint.engine import engine_for

    out = engine_for(structure).beta_at(device_array(z), h, data)
    return tuple(np.asarray(x) for x in out)
