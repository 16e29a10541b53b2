"""The joint model of a legacy protocol table (``chekan-protocol/1``): MAP and Bayesian
re-analysis when only the printed increments survive.

Only the per-angle increments survive, so the model is the characteristic itself
(eq. 21) in the record's convention, per round r, system j and angle i:

    Δg_ref,ri = b_rj x_rji + a x_rji² − g sin θᵢ · δ_ri + e_rji,

with x = m − m_h recovered from the protocol
(:func:`chekan.classical.fit.increments_from_protocol`),
δ_ri the angle-readout error of the ± pair (shared by both systems; the mean of two holds'
errors, variance σ_θ²/2) and e the independent error of each system's pair mean
(variance σ_e²). δ is marginalised: each (r, i) pair of systems is bivariate normal with
covariance σ_e² I + (g sin θᵢ)² σ_θ²/2 · 11ᵀ.

Priors: b_rj ~ N(6.9, 0.5) (wide); a ~ N(a_protocol, (0.25·|a_protocol|)²) — the protocol
fixed a, and only the quadratic curvature of eight points informs it; log σ_θ ~ N(log 2″, 0.5)
(platform readout ≤ 3″); log σ_e ~ N(log 0.3 mGal, 1). ε and Δγ cannot be identified from
pair means and are not reported.

**Systematic angle error** (``options.angle_errors == "systematic"``, the default): the
platform's sensor error also has a part shared by all rounds (:mod:`chekan.joint.angles`).
For the ± pair at angle i it adds to δ_ri

    s_i = (ζ₊ᵢ − ζ₋ᵢ)/2 + ξ·θᵢ/θ_max,

ζ±ᵢ ~ N(0, u²/2) the per-angle error at each sign (the pair term has variance u²/4) and
ξ ~ N(0, u²/2) the scale error at θ_max (the same sign at every angle; u = U/√3, U the
specification's bound). s is linear in the data too and is marginalised in closed form,
but it is shared across rounds, so the likelihood no longer factorises per (r, i): the
residuals of all (r, j, i) are one normal vector with covariance

    σ_e² I + σ_θ²/2 · (g sin θᵢ)² [same r, i] + (g sin θᵢ)(g sin θₖ)(u²/4 [i = k] + u²/2 tᵢtₖ),

tᵢ = θᵢ/θ_max (32 × 32 for the paper's protocol; a dense Cholesky). With
``"independent"`` the model is the per-(r, i) one above, unchanged.

**Uncertainty budget.** At fixed σ_θ, σ_e (the MAP's; the posterior means for bayes) the
estimate of (b, a) is generalised least squares with normal priors, so its covariance
splits exactly, M Xᵀ C⁻¹ (Σ_g C_g) C⁻¹ X M + M P⁻¹ M with M = (Xᵀ C⁻¹ X + P⁻¹)⁻¹, into
``noise`` (σ_e²), ``angle_readout`` (δ, Type A), ``angle_systematic`` (s, Type B), ``a``
(its prior) and ``other_priors`` (the priors of b); each line is scaled to the reported sd.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

import chekan.jaxconfig  # noqa: F401
from chekan.classical.fit import increments_from_protocol
from chekan.errors import ChekanError
from chekan.fit.fitted import RawBudget, Summary
from chekan.joint.angles import AngleSensorSpec, commanded_groups
from chekan.physics.units import ARCSEC_PER_RAD
from chekan.runtime.compiler import Compiler
from inference.map import fit_map
from inference.params import Param, ParamSpace
from inference.problem import LeastSquaresProblem

if TYPE_CHECKING:
    from inference.map import MapResult
    from inference.sampling import SamplingResult


def _space(R: int, a0: float) -> tuple[ParamSpace, ParamSpace]:
    bs = [
        Param(f"b_r{r + 1}_s{j + 1}", loc=6.9, scale=0.5, typical=1e-3, unit="mGal/pix")
        for r in range(R)
        for j in range(2)
    ]
    a = Param("a", loc=a0, scale=0.25 * abs(a0) if a0 else 1e-4, typical=1e-6, unit="mGal/pix^2")
    hyp = [
        Param("sigma_theta_arcsec", loc=math.log(2.0), scale=0.5, transform="log", typical=0.2),
        Param("sigma_e_mgal", loc=math.log(0.3), scale=1.0, transform="log", typical=0.2),
    ]
    return ParamSpace([*bs, a]), ParamSpace([*bs, a, *hyp])


def _data(table) -> dict:
    x = np.nan_to_num(table.x_pix)
    mask = np.isfinite(table.x_pix)
    theta = np.deg2rad(table.angle_deg)
    return {
        "x": jnp.asarray(x),  # (R, 2, n)
        "mask": jnp.asarray(mask),
        "y": jnp.asarray(-np.nan_to_num(table.da_ref_mgal)),  # (R, n) Δg_ref, record convention
        "gs": jnp.asarray(table.g_local_mgal * np.sin(theta) / ARCSEC_PER_RAD),  # mGal per arcsec
    }


def _bmat(v: dict, R: int) -> jax.Array:
    return jnp.stack([jnp.stack([v[f"b_r{r + 1}_s{j + 1}"] for j in range(2)]) for r in range(R)])


def _resid(v, data):
    b = _bmat(v, data["x"].shape[0])
    x = data["x"]
    pred = b[:, :, None] * x + v["a"] * x**2
    return jnp.where(data["mask"], data["y"][:, None, :] - pred, 0.0)  # (R, 2, n)


def _log_lik(v, data):
    """Σ over (r, i) of log N(res (2,); 0, σ_e² I + c² 11ᵀ), c = g sin θ σ_θ/√2 (closed form)."""
    r = _resid(v, data)
    both = data["mask"].all(axis=1)  # (R, n)
    c2 = (data["gs"] * v["sigma_theta_arcsec"]) ** 2 / 2.0  # (n,)
    s2 = v["sigma_e_mgal"] ** 2
    r1, r2 = r[:, 0, :], r[:, 1, :]
    det = s2 * (s2 + 2 * c2)
    quad = ((s2 + c2) * (r1**2 + r2**2) - 2 * c2 * r1 * r2) / det
    ll2 = -0.5 * (quad + jnp.log(det) + 2 * math.log(2 * math.pi))
    # rows with one system only: univariate with variance s2 + c2
    single = data["mask"].any(axis=1) & ~both
    rs = jnp.where(data["mask"][:, 0, :], r1, r2)
    ll1 = -0.5 * (rs**2 / (s2 + c2) + jnp.log(2 * math.pi * (s2 + c2)))
    return jnp.sum(jnp.where(both, ll2, 0.0)) + jnp.sum(jnp.where(single, ll1, 0.0))


def _cov_parts(table, spec: AngleSensorSpec | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over the residual vector (R, 2, n) flattened: D, with σ_θ²·D the covariance of the
    pair errors δ (shared by both systems of one round and angle); S, the covariance of the
    systematic pair errors s (shared by all rounds; zero without a spec); the mask."""
    R, _, n = table.x_pix.shape
    theta = np.abs(np.deg2rad(np.asarray(table.angle_deg, dtype=float)))
    gs = table.g_local_mgal * np.sin(theta) / ARCSEC_PER_RAD  # mGal per arcsec
    rr, _jj, ii = (a.reshape(-1) for a in np.indices((R, 2, n)))
    g = gs[ii]
    gg = np.outer(g, g)
    D = gg * ((rr[:, None] == rr[None, :]) & (ii[:, None] == ii[None, :])) / 2.0
    S = np.zeros_like(D)
    if spec is not None:
        group = commanded_groups(theta)[ii]
        t = (theta / max(float(np.max(theta)), 1e-12))[ii]
        # (ζ₊ − ζ₋)/2 has variance per_angle_var/2; ξ·t acts with one sign at every angle
        S = gg * (
            spec.per_angle_var / 2.0 * (group[:, None] == group[None, :])
            + spec.scale_var * np.outer(t, t)
        )
    return D, S, np.isfinite(table.x_pix).reshape(-1)


def _full_cov(D, S, m, sigma_theta, sigma_e, xp=np):
    """The residuals' covariance; a masked entry is a unit row and column (residual 0)."""
    C = sigma_e**2 * xp.eye(m.size) + sigma_theta**2 * D + S
    return xp.where(m[:, None] & m[None, :], C, xp.eye(m.size))


def _log_lik_dense(v, data):
    """log N(residuals; 0, C) over all (r, j, i) at once: the systematic angle errors are
    shared across rounds (dense Cholesky; the table is tiny)."""
    r = _resid(v, data).reshape(-1)
    C = _full_cov(data["D"], data["S"], data["m"], v["sigma_theta_arcsec"], v["sigma_e_mgal"], jnp)
    L = jnp.linalg.cholesky(C)
    w = jax.scipy.linalg.solve_triangular(L, r, lower=True)
    n_obs = jnp.sum(data["m"])
    return -0.5 * (w @ w + 2.0 * jnp.sum(jnp.log(jnp.diag(L))) + n_obs * math.log(2 * math.pi))


def _budget(table, spec, sigma_theta: float, sigma_e: float, space: ParamSpace) -> dict:
    """Linearised sd of b₁, b₂ (mean over rounds) per source, at fixed σ_θ, σ_e: the exact
    split of the GLS-with-priors covariance M Xᵀ C⁻¹ (Σ C_g) C⁻¹ X M + M P⁻¹ M."""
    R, _, n = table.x_pix.shape
    D, S, m = _cov_parts(table, spec)
    x = np.nan_to_num(table.x_pix)
    names = [p.name for p in space.params]
    X = np.zeros((m.size, len(names)))
    for r in range(R):
        for j in range(2):
            rows = (2 * r + j) * n + np.arange(n)
            X[rows, names.index(f"b_r{r + 1}_s{j + 1}")] = x[r, j]
            X[rows, names.index("a")] = x[r, j] ** 2
    X[~m] = 0.0
    mm = (m[:, None] & m[None, :]).astype(float)
    parts = {
        "noise": sigma_e**2 * np.diag(m.astype(float)),
        "angle_readout": sigma_theta**2 * D * mm,
    }
    if spec is not None:
        parts["angle_systematic"] = S * mm
    C = _full_cov(D, S, m, sigma_theta, sigma_e)
    CiX = np.linalg.solve(C, X)
    prec = np.array([1.0 / p.scale**2 for p in space.params])
    M = np.linalg.inv(X.T @ CiX + np.diag(prec))
    A = M @ CiX.T
    covs = {g: A @ Cg @ A.T for g, Cg in parts.items()}
    is_a = np.array([nm == "a" for nm in names])
    covs["a"] = M @ np.diag(np.where(is_a, prec, 0.0)) @ M
    covs["other_priors"] = M @ np.diag(np.where(is_a, 0.0, prec)) @ M
    out = {}
    for j in range(2):
        w = np.zeros(len(names))
        w[[names.index(f"b_r{r + 1}_s{j + 1}") for r in range(R)]] = 1.0 / R
        var = {g: max(float(w @ V @ w), 0.0) for g, V in covs.items()}
        e = {g: math.sqrt(v) for g, v in var.items()}
        e["total_linearised"] = math.sqrt(sum(var.values()))
        out[f"b{j + 1}"] = e
    return out


@dataclass(frozen=True)
class ProtocolModel:
    """A protocol table laid out for the model: its data, parameter spaces and start."""

    table: Any
    rounds: int
    a0: float  # the protocol's a: the centre of a's prior (record convention)
    theta_space: ParamSpace  # b of each round and system, a
    full_space: ParamSpace  # and the hyperparameters σ_θ, σ_e (sampled by bayes)
    data: dict
    hyp: dict  # the hyperparameters at which the MAP is solved
    spec: AngleSensorSpec | None


@dataclass(frozen=True)
class ProtocolPosterior:
    """The ``bayes`` posterior of a protocol: the sampler's result, the named draws (the
    per-round b and their mean b₁, b₂), their summary and convergence verdict."""

    sampling: SamplingResult
    draws: Mapping[str, np.ndarray]
    summary: Summary
    converged: bool
    problems: tuple[str, ...]


@dataclass(frozen=True)
class ProtocolEstimate:
    """The ``map`` or ``bayes`` fit of a legacy protocol: its model, the MAP, the raw budget
    (at the MAP's hyperparameters; the posterior means for bayes), the posterior (bayes
    only), the NetCDF written (or None) and the seconds taken."""

    model: ProtocolModel
    result: MapResult
    budget: RawBudget
    posterior: ProtocolPosterior | None
    netcdf: Path | None
    seconds: float


def protocol_model(protocol, options) -> ProtocolModel:
    """:class:`ProtocolModel` of ``protocol`` (the covariance of the systematic angle error
    and its whitening where ``options`` model it)."""
    table = increments_from_protocol(protocol)
    if table.a_fixed is None:
        raise ChekanError(f"{protocol.path}: the protocol gives no a (its prior centre)")
    R, a0 = len(table.rounds), float(table.a_fixed)
    theta_space, full_space = _space(R, a0)
    data = _data(table)
    hyp = {"sigma_theta_arcsec": 2.0, "sigma_e_mgal": 0.3}
    spec = options.angle_spec(protocol.meta, source=protocol.path or "protocol")
    if spec is not None:
        D, S, m = _cov_parts(table, spec)
        data.update(D=jnp.asarray(D), S=jnp.asarray(S), m=jnp.asarray(m))
        L = np.linalg.cholesky(_full_cov(D, S, m, *hyp.values()))
        data["Linv"] = jnp.asarray(np.linalg.solve(L, np.eye(m.size)))
    return ProtocolModel(table, R, a0, theta_space, full_space, data, hyp, spec)


def _whitened_residuals(v, d):
    """Whitened residuals at fixed hyperparameters: Cholesky of each 2×2 covariance (of the
    whole covariance with systematic angle errors)."""
    vv = {**v, **d["hyp"]}
    if "Linv" in d:
        return d["Linv"] @ _resid(vv, d).reshape(-1)
    r = _resid(vv, d)
    c2 = (d["gs"] * vv["sigma_theta_arcsec"]) ** 2 / 2.0
    s2 = vv["sigma_e_mgal"] ** 2
    l11 = jnp.sqrt(s2 + c2)
    l21 = c2 / l11
    l22 = jnp.sqrt(s2 + c2 - l21**2)
    w1 = r[:, 0, :] / l11
    w2 = (r[:, 1, :] - l21 * w1) / l22
    return jnp.concatenate([w1.reshape(-1), w2.reshape(-1)])


def estimate_protocol(protocol, *, classical, options) -> ProtocolEstimate:
    """The ``map`` or ``bayes`` fit of a legacy protocol (module docstring), written by
    :func:`chekan.results.joint.protocol_result`."""
    t0 = time.perf_counter()
    pm = protocol_model(protocol, options)
    lsq = LeastSquaresProblem(pm.theta_space, _whitened_residuals, Compiler())
    init = {
        p.name: float(classical.b[int(p.name[3]) - 1, int(p.name[6]) - 1])
        for p in pm.theta_space.params
        if p.name.startswith("b_")
    }
    init["a"] = pm.a0
    mdata = {**pm.data, "hyp": {k: jnp.asarray(v) for k, v in pm.hyp.items()}}
    res = fit_map(lsq, mdata, init)
    if options.method == "map":
        hyp = pm.hyp
        raw = _budget(
            pm.table, pm.spec, hyp["sigma_theta_arcsec"], hyp["sigma_e_mgal"], pm.theta_space
        )
        return ProtocolEstimate(pm, res, raw, None, None, time.perf_counter() - t0)
    post = _posterior(pm, res, options)
    sigma_theta = float(post.summary["sigma_theta_arcsec"]["mean"])
    sigma_e = float(post.summary["sigma_e_mgal"]["mean"])
    raw = _budget(pm.table, pm.spec, sigma_theta, sigma_e, pm.theta_space)
    seconds = time.perf_counter() - t0
    netcdf = None
    if options.netcdf:
        netcdf = _write_netcdf(post.draws, post.sampling, pm, options.netcdf)
    return ProtocolEstimate(pm, res, raw, post, netcdf, seconds)


def _posterior(pm: ProtocolModel, res, options) -> ProtocolPosterior:
    """The posterior of b, a, σ_θ, σ_e, with the mean over rounds of each system's b."""
    from inference.diagnostics import convergence_report, summarize_draws
    from inference.sampling import sample

    samp = sample(
        _log_density(pm),
        pm.data,
        *_sampler_start(pm, res),
        _sampler_config(options),
        executables=Compiler(),
    )
    draws = {k: np.asarray(v) for k, v in pm.full_space.to_values(samp.draws).items()}
    for j in range(2):
        draws[f"b{j + 1}"] = np.mean(
            [draws[f"b_r{r + 1}_s{j + 1}"] for r in range(pm.rounds)], axis=0
        )
    summ = summarize_draws(draws, hdi_prob=options.hdi_prob)
    ok, problems = convergence_report(summ, rhat_max=1.01, ess_min=400)
    return ProtocolPosterior(samp, draws, summ, bool(ok), tuple(problems))


def _log_density(pm: ProtocolModel):
    """log p(b, a, σ_θ, σ_e | table) up to a constant (the angle errors marginalised)."""
    space, dense = pm.full_space, pm.spec is not None

    def log_density(z, d):
        v = space.to_values(z)
        lp = space.log_prior(z) + (_log_lik_dense(v, d) if dense else _log_lik(v, d))
        return jnp.where(jnp.isfinite(lp), lp, -jnp.inf)

    return log_density


def _sampler_start(pm: ProtocolModel, res) -> tuple[np.ndarray, np.ndarray]:
    """The sampler's start: the MAP with the hyperparameters, its covariance (Laplace for
    b and a, 0.25 on the diagonal for the rest)."""
    vals: dict[str, Any] = {**res.values, **pm.hyp}
    z0 = np.asarray(pm.full_space.to_z(vals))
    n = pm.theta_space.size
    cov = np.eye(pm.full_space.size) * 0.25
    if np.all(np.isfinite(res.cov_z)):
        cov[:n, :n] = res.cov_z
    return z0, cov


def _sampler_config(options):
    from inference.sampling import SamplerConfig

    return SamplerConfig(
        n_chains=4,
        target_ess=2000.0,
        min_steps=500,
        max_steps=20000,
        seed=options.seed,
        progress=options.progress,
    )


def _write_netcdf(draws: Mapping[str, np.ndarray], samp, pm: ProtocolModel, path) -> Path:
    from chekan.files.durable import fsync_dir
    from inference.arviz_io import save_netcdf, to_inference_data

    idata = to_inference_data(
        draws,
        sample_stats={"lp": samp.log_prob},
        observed_data={"x_pix": np.asarray(pm.table.x_pix)},
        attrs={"model": "chekan.fit.protocol"},
    )
    return save_netcdf(idata, path, sync_dir=fsync_dir)
