"""MAP and Bayesian estimation of the calibration (``--method map|bayes``).

``map``: optimistix Levenberg–Marquardt on the joint least-squares problem in
(θ, β) with the hyperparameters fixed, alternated three times with their EM updates
(σ_o² = mean(o² + var o), σ_θ² = mean(δ² + var δ), noise scales and κ from the expected
squared residuals); the
Laplace covariance (JᵀJ)⁻¹ gives the standard errors.

``bayes``: emcee on the 12-dimensional marginal posterior p(θ, h | y) (β integrated
out in closed form): the MAP is refined to the marginal mode and its Laplace
approximation (:func:`inference.mode.refine_mode`), which seeds the walkers and an
independence-MH t proposal mixed with DE moves (:func:`sampler_config`); four
independent ensembles for R-hat, burn-in and thinning from the integrated
autocorrelation time; β | θ, y is drawn for every retained draw, so drift, angle
errors, a and b₀ have posteriors too. Convergence (R-hat ≤ 1.01, bulk ESS ≥ 400)
is checked and failures are reported loudly in the result.

The uncertainty budget of b splits the linearised variance of b̂ by the source of
each whitened row of the MAP Jacobian: var b̂ = Σ_rows hᵣ², h = e_bᵀ(JᵀJ)⁻¹Jᵀ.
Groups: noise (data rows), angle readout (δ, e prior rows), hold offsets, drift,
a (prior of K), others; scaled to the posterior sd.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import chekan.jaxconfig  # noqa: F401
from chekan import calmodel as cm
from chekan import model as fm
from chekan.classical import fit_classical, increments_from_holds
from chekan.errors import ChekanError
from chekan.holds import segment_record
from chekan.result import param_entry, posterior_entry
from chekan.units import ARCMIN_PER_RAD, ARCSEC_PER_RAD
from inference.map import fit_map
from inference.normal_eq import draw_beta_normal

MAP_PASSES = 3  # LM solves; between them the hyperparameters are converged at fixed θ
HYPER_TOL = 1e-4  # EM at fixed θ stops when no log-hyperparameter moves more than this
HYPER_MAX_UPDATES = 200  # ~8 ms each on a 9 h record
PARAM_UNITS = {
    "b1": "mGal/pix",
    "b2": "mGal/pix",
    "a": "mGal/pix^2",
    "b1_0": "mGal/pix",
    "b2_0": "mGal/pix",
    "eps1_arcmin": "arcmin",
    "eps2_arcmin": "arcmin",
    "dgamma_arcmin": "arcmin",
    "tau_s": "s",
    "drift1_pix_per_h": "pix/h",
    "drift2_pix_per_h": "pix/h",
    "sigma1_pix": "pix",
    "sigma2_pix": "pix",
    "sigma_theta_arcsec": "arcsec",
    "sigma_hold_pix": "pix",
    "slew_error": "",
}


# ----------------------------------------------------------------------------- set-up


def prepare(record, options) -> tuple:
    """Segment the record into holds and lay it out for the joint model."""
    settle = options.settle_s
    if settle is None:
        settle = float(record.meta.get("program_settle_s", 300.0))
    holds = segment_record(record, settle_s=settle)
    m_ref = np.nanmean(holds.m_mean_pix[holds.is_level], axis=0)
    return holds, cm.prepare_record(record, holds, m_ref, encoder=options.encoder_error)


def setup(record, options):
    """Holds, the record model and its (shared, compiled) problem."""
    holds, model = prepare(record, options)
    return holds, model, problem_for(model)


_PROBLEMS: dict = {}


def problem_for(model: cm.RecordModel) -> cm.CalibrationProblem:
    """One problem object per model structure, so compiled solvers are reused across
    records of the same shape (batch re-analysis, validation studies)."""
    key = (
        model.n_holds,
        model.n_bins,
        model.drift_degree,
        model.encoder_degree,
        tuple(model.data["mv_tx"].shape),
    )
    if key not in _PROBLEMS:
        _PROBLEMS[key] = cm.build_problem(model)
    prob = _PROBLEMS[key]
    return cm.CalibrationProblem(
        model, prob.theta_space, prob.bayes_space, prob.map_space, prob.lsq
    )


def initial_values(classical, g: float) -> dict:
    a = classical.a
    K = float(np.sqrt(g / (2 * a))) if a > 0 else cm.K_DESIGN
    eps = classical.eps_arcmin if classical.eps_arcmin is not None else np.zeros(2)
    return {
        "b1": float(classical.b_mean[0]),
        "b2": float(classical.b_mean[1]),
        "K": K,
        "eps1_arcmin": float(eps[0]),
        "eps2_arcmin": float(eps[1]),
        "dgamma_arcmin": 0.0,
        "tau_s": 30.0,
    }


def fit_map_em(prob: cm.CalibrationProblem, init: dict, *, progress: bool = False):
    """MAP with EM updates of the hyperparameters; returns (MapResult, hyper dict, history).

    ``MAP_PASSES`` LM solves over θ (β projected out). Between two solves the
    hyperparameters are converged at fixed θ (:func:`converge_hyper`): the EM fixed point
    σ_o² = mean(ô² + var o), σ_θ² = mean(δ̂² + var δ) with the conditional variances of β
    from M⁻¹, and (s₁, s₂, κ) from the expected squared residuals r̂² + leverage of all
    bins (:func:`em_update`). A fixed small number of EM updates is not enough: σ_o
    creeps up from its start by ~15 % per update, and stopping early understates the sd
    of b by 5–10 % (z² ≈ 1.2–1.6 in the validation study). Before each update the level
    reference is moved to its estimate (:func:`recentre_level`): this changes
    ``prob.model.data["m_ref"]`` in place, so that whatever uses the model afterwards (the
    derived quantities, the sampler) sees the same reference as the fit.
    """
    model = prob.model
    h = cm.hyper_dict()
    z = prob.map_space.to_z(init)
    history = []
    res = None
    for it in range(MAP_PASSES):
        res = fit_map(prob.lsq, {**model.data, "hyper": h}, z)
        z = res.z
        updates = 0
        if it < MAP_PASSES - 1:
            h, updates = between_passes(prob, z, h)
        history.append(_pass_entry(it, res.converged, res.num_steps, res.cost, progress, updates))
    return res, h, history


def between_passes(prob: cm.CalibrationProblem, z, h: dict) -> tuple[dict, int]:
    """What follows every LM pass but the last: :func:`recentre_level`, then
    :func:`converge_hyper`. Returns the new hyperparameters and the number of EM updates."""
    recentre_level(prob, z, h)
    return converge_hyper(prob, z, h)


def recentre_level(prob: cm.CalibrationProblem, z, h: dict) -> np.ndarray:
    """Move the reference level reading to the estimate, m_ref ← m_ref + ĉ (in place in
    ``prob.model.data``); returns ĉ (pix).

    The equilibrium Eₖ is computed about m_ref (its position φ_h = (m_ref − m₀)/K on the
    torsion characteristic, and b is dG/dm there), while c only shifts the readings. The
    classical m_h that m_ref starts from is biased when the level holds have not settled
    (slow damping, short dwells: 17 pix at τ = 90 s on the 3 h program), and an additive
    shift does not move the curvature with it: that bias went into b (≈ +0.5 sd). After
    one pass ĉ is known to ~0.01 pix, so the next pass evaluates Eₖ about the estimated
    level itself.
    """
    data = prob.model.data
    _, beta, *_ = _beta_at(prob, z, h, {**data, "hyper": h})
    c = np.asarray(beta)[prob.model.beta_blocks["c"]]
    data["m_ref"] = jnp.asarray(np.asarray(data["m_ref"]) + c)
    return c


def converge_hyper(prob: cm.CalibrationProblem, z, h: dict) -> tuple[dict, int]:
    """EM updates (:func:`em_update`) at fixed θ = z until no log-hyperparameter moves by
    more than ``HYPER_TOL``: the hyperparameters of largest marginal likelihood given θ.
    Returns them and the number of updates made."""
    n, change = 0, np.inf
    while change >= HYPER_TOL and n < HYPER_MAX_UPDATES:
        new = em_update(prob, z, h, {**prob.model.data, "hyper": h})
        change = max(float(np.max(np.abs(np.log(new[k]) - np.log(h[k])))) for k in h)
        h, n = new, n + 1
    return h, n


def _pass_entry(it: int, converged, steps, cost, progress: bool, hyper_updates: int) -> dict:
    if progress:
        tail = f", then {hyper_updates} EM updates of the hyperparameters" if hyper_updates else ""
        print(
            f"  MAP pass {it + 1}: {'converged' if converged else 'NOT converged'} "
            f"in {int(steps)} steps, cost {float(cost):.1f}{tail}"
        )
    return {
        "iteration": it,
        "converged": bool(converged),
        "steps": int(steps),
        "cost": float(cost),
        "hyper_updates": int(hyper_updates),
    }


def em_update(prob: cm.CalibrationProblem, z, h: dict, data: dict) -> dict:
    """One EM update of the hyperparameters at θ = z (real holds and bins only)."""
    blocks = prob.model.beta_blocks
    mask = np.asarray(data["mask"])
    hold = np.asarray(data["hold_mask"])
    rw, beta, var, base, trans, lev = _beta_at(prob, z, h, data)
    o_sel = blocks["hold_offset"][np.tile(hold, 2)]
    d_sel = blocks["angle_error"][hold]
    o, vo = beta[o_sel], var[o_sel]
    d, vd = beta[d_sel], var[d_sel]
    r = rw.reshape(mask.shape)
    nv = base + (float(h["slew_error"]) * trans) ** 2
    e2 = np.where(mask, (r**2 + lev) * nv, 0.0)  # E[squared residual | y] in pix²
    scale, kappa = _noise_m_step(e2, base / np.asarray(h["noise_scale"])[None, :] ** 2, trans, mask)
    return cm.hyper_dict(
        noise_scale=scale,
        sigma_theta_arcsec=float(np.clip(np.sqrt(np.mean(d**2 + vd)), 0.05, 30.0)),
        sigma_hold_pix=float(np.clip(np.sqrt(np.mean(o**2 + vo)), 1e-3, 5.0)),
        slew_error=kappa,
    )


def _noise_m_step(e2, b0, trans, mask) -> tuple[np.ndarray, float]:
    """(s₁, s₂, κ) maximising Σ −½(log v + E[e²]/v) + log-priors, v = sⱼ² b₀ + κ² t².

    All bins at once: settled bins (t = 0) fix sⱼ, the settling ones then fix κ. Priors
    as in :func:`chekan.calmodel.hyper_params` (log s ~ N(0, 0.5), log κ ~ N(log 0.003, 1.5)).
    """
    from scipy.optimize import minimize

    m = mask.astype(float)
    t2 = trans**2
    k_loc, k_sd, s_sd = np.log(0.003), 1.5, 0.5

    def f(x):
        ls, lk = x[:2], x[2]
        v = np.exp(2 * ls)[None, :] * b0 + np.exp(2 * lk) * t2
        v = np.where(mask, v, 1.0)
        q = m * (1.0 / v - e2 / v**2)  # ∂(log v + e²/v)/∂v
        val = 0.5 * np.sum(m * (np.log(v) + e2 / v))
        val += 0.5 * np.sum((ls / s_sd) ** 2) + 0.5 * ((lk - k_loc) / k_sd) ** 2
        g_s = np.sum(q * np.exp(2 * ls)[None, :] * b0, axis=0) + ls / s_sd**2
        g_k = np.sum(q * np.exp(2 * lk) * t2) + (lk - k_loc) / k_sd**2
        return val, np.concatenate([g_s, [g_k]])

    x0 = np.array([0.0, 0.0, k_loc])
    bounds = [(np.log(0.05), np.log(50.0))] * 2 + [(np.log(1e-5), np.log(0.5))]
    res = minimize(f, x0, jac=True, method="L-BFGS-B", bounds=bounds)
    return np.exp(res.x[:2]), float(np.exp(res.x[2]))


_JITTED: dict = {}


def _jitted_for(prob: cm.CalibrationProblem, name: str, make):
    """``jax.jit(make(prob))``, built once per problem structure (``problem_for`` shares
    ``prob.lsq`` between records of one shape; the entry keeps ``prob`` alive, so its id
    is never reused)."""
    key = (name, id(prob.lsq))
    if key not in _JITTED:
        _JITTED[key] = (prob, jax.jit(make(prob)))
    return _JITTED[key][1]


def _beta_at_fn(prob):
    def fn(z, h, data):
        v = prob.map_space.to_values(z)
        rw, beta, L, (_, G, s, _, _, nv, trans) = cm.solve_beta(v, h, prob.model, data, extras=True)
        Linv = jax.scipy.linalg.solve_triangular(L, jnp.eye(L.shape[0]), lower=True)
        # leverage of each bin: (Ã M⁻¹ Ãᵀ)ᵢᵢ with Ã the whitened design (E[r²] = r̂² + lev)
        A = cm.dense_design(G, s, prob.model, data)  # (N, 2, p)
        sw = jnp.where(data["mask"], 1.0 / jnp.sqrt(nv), 0.0)
        X = jnp.einsum("qp,njp->njq", Linv, A * sw[..., None])
        lev = jnp.sum(X**2, axis=-1)
        return rw, beta, jnp.sum(Linv**2, axis=0), cm.noise_var(h, data), trans, lev

    return fn


def _beta_at(prob, z, h, data):
    """β̂, its conditional variances diag(M⁻¹), the whitened residuals, the base noise
    variance, the transient amplitudes and the bins' leverages at θ = z."""
    out = _jitted_for(prob, "beta_at", _beta_at_fn)(jnp.asarray(z), h, data)
    return tuple(np.asarray(x) for x in out)


# ----------------------------------------------------------------------------- derived


def _derived_fn(prob: cm.CalibrationProblem):
    """(z_bayes, key) → named draws of everything reported (β drawn given θ)."""
    model = prob.model
    space = prob.bayes_space
    blocks = model.beta_blocks
    D = model.drift_degree
    dur_h = (model.t_span_s[1] - model.t_span_s[0]) / 3600.0
    ends = np.array([1.0 - (-1.0) ** ell for ell in range(1, D + 1)])  # P_l(1) − P_l(−1)

    def one(z, key, data):
        v = space.to_values(z)
        ne, (_, G, s_ang, r, _, nv, _) = cm.normal_equations(v, v, model, data)
        beta = draw_beta_normal(key, ne, cm.beta_prior_var(v, model))
        # pointwise log-likelihood of each bin mean given this draw's (θ, β): conditional,
        # because the marginal over β does not factorise over bins
        res_b = r - cm.apply_A(beta, G, s_ang, model, data)
        loglik = jnp.where(data["mask"], -0.5 * (res_b**2 / nv + jnp.log(2 * jnp.pi * nv)), 0.0)
        c = beta[blocks["c"]]
        sp = cm.sensor_params(v, data, c)
        a_sys = fm.quadratic_coefficient(sp, sp.m_level_pix)
        b0 = fm.scale_factor_at_centre(sp)
        dr = beta[blocks["drift"]].reshape(2, D)
        slope = dr @ jnp.asarray(ends) / dur_h
        delta = beta[blocks["angle_error"]]
        if model.encoder_degree:
            delta = delta + data["enc_basis"] @ beta[blocks["encoder"]]
        sig = v["noise_scale"] * data["sigma_base"]
        return {
            "b1": v["b1"],
            "b2": v["b2"],
            "a": jnp.mean(a_sys),
            "b1_0": b0[0],
            "b2_0": b0[1],
            "eps1_arcmin": v["eps1_arcmin"],
            "eps2_arcmin": v["eps2_arcmin"],
            "dgamma_arcmin": v["dgamma_arcmin"],
            "tau_s": v["tau_s"],
            "drift1_pix_per_h": slope[0],
            "drift2_pix_per_h": slope[1],
            "sigma1_pix": sig[0],
            "sigma2_pix": sig[1],
            "sigma_theta_arcsec": v["sigma_theta_arcsec"],
            "sigma_hold_pix": v["sigma_hold_pix"],
            "slew_error": v["slew_error"],
            "m_level_pix": sp.m_level_pix,
            "drift_coeffs": dr,
            "angle_error_arcsec": delta,
            "hold_offset_pix": beta[blocks["hold_offset"]].reshape(2, -1).T,
            "_loglik": loglik,
        }

    def many(zs, keys, data):
        # lax.map, not vmap: XLA on CPU compiles/executes batched factorisations of this size
        # pathologically slowly (batch 8: 9 ms; batch 16: minutes); a loop is fast and predictable
        return jax.lax.map(lambda zk: one(zk[0], zk[1], data), (zs, keys))

    return jax.jit(many)


def _in_chunks(fn, zs: np.ndarray, keys, data, chunk: int = 512) -> dict:
    """Apply a vmapped ``fn(z, key, data)`` to many draws in fixed-size chunks (one compile,
    bounded memory: each draw assembles a p×p normal-equation matrix)."""
    n = zs.shape[0]
    pad = (-n) % chunk
    zp = np.concatenate([zs, np.repeat(zs[-1:], pad, axis=0)])
    kp = jnp.concatenate([keys, jnp.repeat(keys[-1:], pad, axis=0)])
    parts = [
        fn(jnp.asarray(zp[i : i + chunk]), kp[i : i + chunk], data)
        for i in range(0, n + pad, chunk)
    ]
    return {k: np.concatenate([np.asarray(p[k]) for p in parts])[:n] for k in parts[0]}


def _map_derived_core(prob):
    """(z, h, data, dur_h) → (g, ∂g/∂z total, ∂g/∂β, M⁻¹, β̂), jitted by the caller
    (eager ``jacfwd`` would compile op by op in every new process, uncached)."""
    model = prob.model
    space = prob.map_space
    blocks = model.beta_blocks
    D = model.drift_degree
    ends = jnp.asarray([1.0 - (-1.0) ** ell for ell in range(1, D + 1)])

    def core(z, h, data, dur_h):
        def g(z, beta):
            v = space.to_values(z)
            sp = cm.sensor_params(v, data, beta[blocks["c"]])
            b0 = fm.scale_factor_at_centre(sp)
            slope = beta[blocks["drift"]].reshape(2, D) @ ends / dur_h
            return jnp.stack(
                [
                    v["b1"],
                    v["b2"],
                    jnp.mean(fm.quadratic_coefficient(sp, sp.m_level_pix)),
                    b0[0],
                    b0[1],
                    v["eps1_arcmin"],
                    v["eps2_arcmin"],
                    v["dgamma_arcmin"],
                    v["tau_s"],
                    slope[0],
                    slope[1],
                ]
            )

        def beta_hat(z):
            return cm.solve_beta(space.to_values(z), h, model, data)[1]

        _, beta, L = cm.solve_beta(space.to_values(z), h, model, data)
        Jz = jax.jacfwd(lambda zz: g(zz, beta_hat(zz)))(z)
        Jb = jax.jacfwd(lambda bb: g(z, bb))(beta)
        Linv = jax.scipy.linalg.solve_triangular(L, jnp.eye(L.shape[0]), lower=True)
        return g(z, beta), Jz, Jb, Linv.T @ Linv, beta

    return core


def map_derived(prob, res, h, data):
    """Derived quantities at the MAP with delta-method sds.

    With θ ~ N(θ̂, C) and β | θ ~ N(β̂(θ), M⁻¹):
    var g = (∂g/∂θ + ∂g/∂β ∂β̂/∂θ) C (…)ᵀ + ∂g/∂β M⁻¹ (∂g/∂β)ᵀ.
    """
    model = prob.model
    blocks = model.beta_blocks
    dur_h = (model.t_span_s[1] - model.t_span_s[0]) / 3600.0
    names = list(PARAM_UNITS)[:11]  # b1 … drift2_pix_per_h, in the order g() stacks them
    out_j = _jitted_for(prob, "map_derived", _map_derived_core)(jnp.asarray(res.z), h, data, dur_h)
    val, Jz, Jb, Minv, beta = (np.asarray(x) for x in out_j)
    cov = np.asarray(res.cov_z)
    finite = np.isfinite(np.diag(cov))
    cz = np.where(np.isfinite(cov), cov, 0.0)
    var = np.einsum("ij,jk,ik->i", Jz, cz, Jz) + np.einsum("ij,jk,ik->i", Jb, Minv, Jb)
    sd = np.sqrt(np.maximum(var, 0.0))
    if not finite.all():
        sd = np.where(np.abs(Jz[:, ~finite]).sum(axis=1) > 0, np.inf, sd)
    out = {n: (float(val[i]), float(sd[i])) for i, n in enumerate(names)}
    s = np.asarray(h["noise_scale"]) * np.asarray(data["sigma_base"])
    out["sigma1_pix"] = (float(s[0]), None)
    out["sigma2_pix"] = (float(s[1]), None)
    out["sigma_theta_arcsec"] = (float(h["sigma_theta_arcsec"]), None)
    out["sigma_hold_pix"] = (float(h["sigma_hold_pix"]), None)
    out["slew_error"] = (float(h["slew_error"]), None)
    out["_m_level"] = np.asarray(data["m_ref"]) + np.asarray(beta)[blocks["c"]]
    return out


def uncertainty_budget(prob, res, data) -> dict:
    """Split var(b̂) by the source of each row of the whitened MAP Jacobian (module doc)."""
    space = prob.map_space
    model = prob.model
    jac = _jitted_for(prob, "jacobian", lambda p: jax.jacfwd(p.lsq.stacked_residuals))
    J = np.asarray(jac(jnp.asarray(res.z), data))
    n_data = int(np.asarray(data["mask"]).size)
    nb = model.n_beta
    blocks = model.beta_blocks
    groups = {"noise": np.arange(n_data)}
    off = n_data
    for name, key in (
        ("level_offset", "c"),
        ("drift", "drift"),
        ("hold_offsets", "hold_offset"),
        ("angle_readout", "angle_error"),
        ("angle_readout", "encoder"),
    ):
        groups.setdefault(name, np.zeros(0, int))
        groups[name] = np.concatenate([groups[name], off + blocks[key]])
    off += nb
    prior_rows = [p for p in space.params if p.has_prior]
    idx = off
    for p in prior_rows:
        key = "a" if p.name == "K" else "other_priors"
        groups.setdefault(key, np.zeros(0, int))
        groups[key] = np.concatenate([groups[key], np.arange(idx, idx + p.size)])
        idx += p.size
    JtJ = J.T @ J
    H = np.linalg.pinv(JtJ) @ J.T  # (nz, rows)
    step = space.step
    out = {}
    for name in ("b1", "b2"):
        i = space.flat_indices([name])[0]
        h = H[i] * step[i]
        total = float(np.sum(h**2))
        out[name] = {
            g: float(np.sqrt(np.sum(h[rows] ** 2))) for g, rows in groups.items() if rows.size
        }
        out[name]["total_linearised"] = float(np.sqrt(total))
    return out


# ----------------------------------------------------------------------------- predictive


def posterior_predictive_delta_g(holds, g_local, draws: dict, model, rng, a_fixed=None, n_max=200):
    """Replicate the settled hold means from posterior draws and redo the classical δg.

    For each draw: ŷₖⱼ = Eₖⱼ(θ) + cⱼ + driftⱼ(tₖ) + õₖⱼ − Sₖⱼ δ̃ₖ + noise/√nₖ with fresh
    hold offsets and angle errors (a replicated session), then pairs, level
    interpolation and the least squares of eq. (21) exactly as the classical method.
    """
    n = draws["b1"].size
    take = rng.choice(n, size=min(n, n_max), replace=False)
    flat = {k: np.asarray(v).reshape(n, *np.asarray(v).shape[2:]) for k, v in draws.items()}
    t0, t1 = model.t_span_s
    s = 2.0 * (holds.t_mid_s - t0) / max(t1 - t0, 1.0) - 1.0
    P = np.polynomial.legendre.legvander(np.nan_to_num(s), model.drift_degree)[:, 1:]
    reps = []
    g = float(g_local)
    for i in take:
        sp = fm.make_params(
            g_mgal=g,
            K_pix_per_rad=float(np.sqrt(g / 2 / flat["a"][i])) if flat["a"][i] > 0 else cm.K_DESIGN,
            b_mgal_per_pix=[flat["b1"][i], flat["b2"][i]],
            m_level_pix=flat["m_level_pix"][i],
            eps_rad=np.array([flat["eps1_arcmin"][i], flat["eps2_arcmin"][i]]) / ARCMIN_PER_RAD,
            gamma_rad=flat["dgamma_arcmin"][i] / ARCMIN_PER_RAD,
        )
        E = np.asarray(fm.equilibrium_readings(sp, holds.tilt_x_rad, holds.tilt_y_rad))
        S = np.asarray(fm.reading_sensitivity_to_tilt(sp, holds.tilt_x_rad, holds.tilt_y_rad))
        drift = P @ flat["drift_coeffs"][i].T
        o = rng.normal(0, flat["sigma_hold_pix"][i], E.shape)
        d = rng.normal(0, flat["sigma_theta_arcsec"][i], E.shape[0]) / ARCSEC_PER_RAD
        noise = rng.normal(0, 1, E.shape) * np.array([flat["sigma1_pix"][i], flat["sigma2_pix"][i]])
        y = E + drift + o - S * d[:, None] + noise / np.sqrt(np.maximum(holds.n_used, 1))[:, None]
        rep = holds.__class__(**{**holds.__dict__, "m_mean_pix": y})
        cres = fit_classical(increments_from_holds(rep, g), a_fixed=a_fixed)
        reps.append(cres.delta_g_mgal)
    return np.stack(reps)  # (draws, R, 2, n)


# ----------------------------------------------------------------------------- entry


def estimate(data, *, kind: str, classical, base: dict, options) -> dict:
    """Run ``map`` or ``bayes`` on a record or protocol; return the result dict."""
    if kind == "protocol":
        from chekan.bayes_protocol import estimate_protocol

        return estimate_protocol(data, classical=classical, base=base, options=options)
    t_start = time.perf_counter()
    record = data
    holds, model, prob = setup(record, options)
    init = initial_values(classical, record.g_local_mgal)
    if options.progress:
        print(
            f"model: {model.n_holds} holds, {model.n_bins} bins × 2 systems, "
            f"{model.n_beta} marginalised linear parameters"
        )
    res, h, history = fit_map_em(prob, init, progress=options.progress)
    return after_map(prob, holds, res, h, history, base, options, t_start, record)


def after_map(prob, holds, res, h, history, base, options, t_start, record) -> dict:
    """From the MAP (θ̂, hyperparameters) to the ``map`` result, or on to the sampler."""
    model = prob.model
    mdata = dict(model.data)
    mdata["hyper"] = h
    out = dict(base)
    out["method"] = options.method
    out["classical"] = {k: base["parameters"][k] for k in ("b1", "b2") if k in base["parameters"]}
    budget_raw = uncertainty_budget(prob, res, mdata)
    md = map_derived(prob, res, h, mdata)
    diag = {
        "converged": bool(res.converged),
        "map_steps": int(res.num_steps),
        "map_passes": history,
        "jacobian_cond": float(res.jacobian_cond),
        "not_identified": list(res.degenerate),
        "data": "bin means inside holds (lag modelled), β marginalised",
        "problems": [],
    }
    if not res.converged:
        diag["problems"].append(f"MAP did not converge: {res.message}")
    hp = options.hdi_prob
    if options.method == "map":
        params = {}
        for name, (mean, sd) in md.items():
            if name.startswith("_"):
                continue
            params[name] = param_entry(mean, sd, hp, PARAM_UNITS.get(name, ""))
        out["parameters"] = params
        out["level_reading_pix"] = {"m1": float(md["_m_level"][0]), "m2": float(md["_m_level"][1])}
        out["uncertainty_budget"] = _budget_entries(budget_raw, params)
        _flag_prior_dominated(params, diag)
        diag["seconds"] = time.perf_counter() - t_start
        out["diagnostics"] = diag
        return out
    return _sample(prob, model, holds, res, h, out, diag, budget_raw, options, t_start, record)


PRIOR_SD = {"eps1_arcmin": 10.0, "eps2_arcmin": 10.0, "dgamma_arcmin": 10.0}


def _flag_prior_dominated(params: dict, diag: dict) -> None:
    """Identifiability: a posterior sd above half the prior sd means the data say little."""
    dominated = [
        n for n, psd in PRIOR_SD.items() if n in params and (params[n]["sd"] or 0) > 0.5 * psd
    ]
    diag["prior_dominated"] = dominated
    for n in dominated:
        diag.setdefault("notes", []).append(
            f"{n} is prior-dominated (sd {params[n]['sd']:.3g} vs prior sd {PRIOR_SD[n]:g}): "
            "this program cannot separate it"
        )


def _budget_entries(budget_raw: dict, params: dict) -> dict:
    out = {}
    for name in ("b1", "b2"):
        raw = dict(budget_raw[name])
        lin = raw.pop("total_linearised")
        sd = params[name]["sd"]
        scale = sd / lin if lin > 0 and sd else 1.0
        e = {k: v * scale for k, v in raw.items()}
        e["total"] = sd
        e["expanded_k2"] = 2.0 * sd if sd is not None else None
        out[name] = e
    return out


def sampler_config(options, **overrides):
    """The sampler settings of ``--method bayes``.

    Four independent ensembles (for R̂) of 26 walkers; independence MH (0.7) with a t
    proposal at the Laplace approximation of the marginal posterior (hyperparameters
    included) + DE (0.3), whose τ on this posterior is a few steps (DE alone: ~40–90).
    Stop at ≥ 200 steps, ≥ 25 τ and emcee's ESS estimate ≥ 1000 (bulk ESS ≥ 400 per
    parameter with margin); keep ≤ 2000 draws per chain (1000 left the tail ESS of the
    hyperparameters near 400 on 3 h records).
    """
    from inference.sampling import SamplerConfig

    kw = {
        "n_chains": 4,
        "moves": "de-independence",
        "min_steps": 200,
        "max_steps": 3000 if options.quick else 10000,
        "check_every": 50,
        "tau_factor": 25.0,
        "target_ess": 1000.0,
        "max_draws": 2000,
        "seed": options.seed,
        "progress": options.progress,
    }
    kw.update(overrides)
    return SamplerConfig(**kw)


def _sample(prob, model, holds, res, h, out, diag, budget_raw, options, t_start, record):
    from inference.sampling import sample

    space = prob.bayes_space
    ntheta = prob.theta_space.size
    values = {p.name: res.values[p.name] for p in prob.theta_space.params}
    values.update({k: np.asarray(v) for k, v in h.items()})
    z0 = np.asarray(space.to_z(values))
    cov = np.eye(space.size) * 0.25
    ct = np.asarray(res.cov_z)[:ntheta, :ntheta]
    if np.all(np.isfinite(ct)):
        cov[:ntheta, :ntheta] = ct
    cfg = sampler_config(options)
    if options.progress:
        print("sampling the posterior (emcee, 4 independent ensembles)…")
    data = model.data
    samp = sample(prob.log_density, data, z0, cov, cfg)
    C, Dn = samp.draws.shape[:2]
    keys = jax.random.split(jax.random.PRNGKey(options.seed), C * Dn)
    derived = _in_chunks(_derived_fn(prob), samp.draws.reshape(C * Dn, -1), keys, data)
    draws = {k: v.reshape(C, Dn, *v.shape[1:]) for k, v in derived.items()}
    from inference.diagnostics import convergence_report, summarize_draws

    scalar = {k: v for k, v in draws.items() if v.ndim == 2}
    summ = summarize_draws(scalar, hdi_prob=options.hdi_prob)
    ok, problems = convergence_report(summ, rhat_max=1.01, ess_min=400)
    params = {name: posterior_entry(summ[name], unit) for name, unit in PARAM_UNITS.items()}
    out["parameters"] = params
    mh = draws["m_level_pix"].reshape(-1, 2).mean(axis=0)
    out["level_reading_pix"] = {"m1": float(mh[0]), "m2": float(mh[1])}
    out["uncertainty_budget"] = _budget_entries(budget_raw, params)
    _flag_prior_dominated(params, diag)
    diag["problems"] = diag["problems"] + problems
    diag.update(
        converged=bool(ok and res.converged),
        r_hat_max=float(max(params[n]["r_hat"] for n in params)),
        ess_bulk_min=float(min(params[n]["ess_bulk"] for n in params)),
        n_draws=int(C * Dn),
        n_chains=int(C),
        n_walkers=int(samp.n_walkers),
        n_steps=int(samp.n_steps),
        burn=int(samp.burn),
        thin=int(samp.thin),
        tau_max=float(np.max(samp.tau)),
        acceptance=[float(a) for a in samp.acceptance],
        sampler_message=samp.message,
        seconds=time.perf_counter() - t_start,
    )
    if not diag["converged"]:
        msg = "; ".join(diag["problems"]) or "not converged"
        warnings.warn(f"posterior NOT converged: {msg}", RuntimeWarning, stacklevel=2)
        if options.progress:
            print(f"WARNING: posterior NOT converged: {msg}")
    out["diagnostics"] = diag
    # posterior predictive of the paper's residual table
    rng = np.random.default_rng(options.seed)
    rep = posterior_predictive_delta_g(
        holds, record.g_local_mgal, draws, model, rng, options.a_fixed
    )
    rs = out.get("residuals_mgal", {})
    cols = rs.get("columns", [])
    lo, hi = (1 - options.hdi_prob) / 2 * 100, (1 + options.hdi_prob) / 2 * 100
    out["posterior_predictive_mgal"] = {
        "columns": cols,
        "delta_g_mean": {
            c: list(np.nanmean(rep[:, i // 2, i % 2], axis=0)) for i, c in enumerate(cols)
        },
        "delta_g_low": {
            c: list(np.nanpercentile(rep[:, i // 2, i % 2], lo, axis=0)) for i, c in enumerate(cols)
        },
        "delta_g_high": {
            c: list(np.nanpercentile(rep[:, i // 2, i % 2], hi, axis=0)) for i, c in enumerate(cols)
        },
        "rms_mgal_mean": float(np.nanmean(np.sqrt(np.nanmean(rep**2, axis=-1)))),
        "n_replicates": int(rep.shape[0]),
    }
    out["drift_curve"] = _drift_curve(draws, model, hp=options.hdi_prob)
    out["angle_error_arcsec"] = {
        "step": [int(s) for s in model.hold_steps],
        "mean": list(draws["angle_error_arcsec"].reshape(C * Dn, -1).mean(axis=0)),
        "sd": list(draws["angle_error_arcsec"].reshape(C * Dn, -1).std(axis=0)),
    }
    if options.netcdf:
        out["posterior_netcdf"] = str(_write_netcdf(options.netcdf, draws, samp, model, rep, cols))
    return out


def _drift_curve(draws, model, hp: float, n: int = 60) -> dict:
    t0, t1 = model.t_span_s
    t = np.linspace(t0, t1, n)
    s = 2.0 * (t - t0) / max(t1 - t0, 1.0) - 1.0
    P = np.polynomial.legendre.legvander(s, model.drift_degree)[:, 1:]
    P0 = np.polynomial.legendre.legvander(np.array([-1.0]), model.drift_degree)[:, 1:]
    dr = draws["drift_coeffs"].reshape(-1, 2, model.drift_degree)
    curves = np.einsum("tk,djk->dtj", P - P0, dr)  # relative to the start
    lo, hi = (1 - hp) / 2 * 100, (1 + hp) / 2 * 100
    out = {"t_h": list((t - t0) / 3600.0)}
    for j in range(2):
        out[f"m{j + 1}_pix"] = list(curves[:, :, j].mean(axis=0))
        out[f"m{j + 1}_low"] = list(np.percentile(curves[:, :, j], lo, axis=0))
        out[f"m{j + 1}_high"] = list(np.percentile(curves[:, :, j], hi, axis=0))
    return out


def _write_netcdf(path, draws, samp, model, rep, cols) -> Path:
    from inference.arviz_io import save_netcdf, to_inference_data

    C, Dn = samp.draws.shape[:2]
    post = {k: v for k, v in draws.items() if not k.startswith("_")}
    y = np.asarray(model.data["y"])
    mask = np.asarray(model.data["mask"])
    nrep = rep.shape[0]
    idata = to_inference_data(
        post,
        sample_stats={"lp": samp.log_prob},
        observed_data={"bin_mean_pix": np.where(mask, y, np.nan)},
        posterior_predictive={
            "delta_g_mgal": np.broadcast_to(
                rep.reshape(1, nrep, len(cols) // 2, 2, -1).reshape(1, nrep, len(cols), -1),
                (1, nrep, len(cols), rep.shape[-1]),
            )
        },
        log_likelihood={"bin_mean_pix": draws["_loglik"]},
        coords={"hold": [int(s) for s in model.hold_steps], "system": [1, 2], "column": cols},
        dims={
            "angle_error_arcsec": ["hold"],
            "hold_offset_pix": ["hold", "system"],
            "m_level_pix": ["system"],
            "drift_coeffs": ["system", "degree"],
            "bin_mean_pix": ["bin", "system"],
            "delta_g_mgal": ["column", "angle"],
        },
        attrs={"model": "chekan.calmodel", "draws": f"{C}×{Dn}"},
    )
    return save_netcdf(idata, path)


__all__ = [
    "ChekanError",
    "estimate",
    "fit_map_em",
    "initial_values",
    "map_derived",
    "prepare",
    "problem_for",
    "setup",
]
