"""``--method bayes``: emcee on the 12-dimensional marginal posterior p(θ, h | y).

The MAP is refined to the marginal mode and its Laplace approximation
(:func:`inference.mode.refine_mode`, inside :func:`inference.sampling.sample`), from which an
independence-MH proposal is fitted by importance sampling (:func:`sampler_config`); four
independent ensembles for R-hat, burn-in from the integrated autocorrelation time, stopped
on the bulk ESS and R̂ of the draws it keeps and of every quantity reported from them. The
draws of θ and h are returned with those quantities
(:func:`chekan.fit.reported.posterior_draws`, β drawn given θ).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

import numpy as np

from chekan.fit.map import MapFit
from chekan.joint.layout import RecordModel
from chekan.options import CalibrationOptions
from chekan.runtime.engine import problem_for
from chekan.runtime.padding import split_keys

if TYPE_CHECKING:
    from chekan.fit.reported import ReportedDraws
    from inference.sampling import SamplingResult


def sampler_config(options: CalibrationOptions, **overrides):
    """The sampler settings of ``--method bayes``.

    Four independent ensembles (for R̂) of 26 walkers, moved by independence MH alone with
    a proposal fitted to the posterior (:func:`inference.proposal.fit_proposal`): 1024
    importance draws of a t₅ at the Laplace approximation of the marginal posterior (the
    mode refined with the hyperparameters) fit one Gaussian (weight 0.8); a defensive t₃ at
    the mode, covariance × 1.2² (0.1); and a *shoulder* t₃ (0.1 shared) for every
    coordinate whose Laplace sd is at least a tenth of its prior's, its variance raised to
    the prior's: a hyperparameter whose likelihood flattens towards zero (the slew error's
    log κ) keeps the prior's tail, 5–8 Laplace sds out, where the fitted part has no mass
    and a walker would wait 10⁴–10⁵ steps for a proposal. Stop when the draws that would be
    kept (burn-in 2τ, at most 750 per chain) have rank-normalised bulk ESS ≥ 1000 and rank
    R̂ ≤ 1.01 across the ensembles for every coordinate and, once those pass, for every
    reported quantity (a, b₀ and the drifts carry fresh draws of β | θ:
    :func:`sample_posterior`), and n ≥ 10 τ (checked every 5 steps; tuning:
    ``docs/tuning.md``).
    """
    from inference.sampler_config import SamplerConfig  # not via inference.sampling: emcee

    kw: dict[str, Any] = {
        "n_chains": 4,
        "moves": "adaptive-independence",
        "proposal_scale": 1.0,
        "proposal_points": 1024,
        "proposal_components": 1,
        "proposal_alpha": 0.1,
        "proposal_tail_scale": 1.2,
        "proposal_tail_df": 3.0,
        "de_weight": 0.0,
        "proposal_shoulder_weight": 0.1,
        "proposal_shoulder_ratio": 0.1,
        "stop_rule": "bulk",
        "rhat_max": 1.01,
        "min_steps": 0,
        "max_steps": 3000 if options.quick else 10000,
        "check_every": 5,
        "tau_factor": 10.0,
        "target_ess": 1000.0,
        "max_draws": 750,
        "seed": options.seed,
        "progress": options.progress,
        "sampler": options.sampler,
    }
    kw.update(overrides)
    return SamplerConfig(**kw)


def sample_posterior(fit: MapFit, options: CalibrationOptions) -> SamplingResult:
    """Draws of (θ, h) from the marginal posterior, started at the MAP, with the sampler's
    statistics, and every reported quantity of the kept draws (``SamplingResult.derived``,
    a :class:`~chekan.fit.reported.ReportedDraws`: :func:`reported_draws`, on which the
    stopping rule is checked too)."""
    from inference.sampling import sample

    prob = problem_for(fit.model.structure)
    space = prob.bayes_space
    ntheta = prob.theta_space.size
    res = fit.result
    values = {p.name: res.values[p.name] for p in prob.theta_space.params}
    values.update({k: np.asarray(v) for k, v in fit.hyper.items()})
    z0 = np.asarray(space.to_z(values))
    cov = np.eye(space.size) * 0.25
    ct = np.asarray(res.cov_z)[:ntheta, :ntheta]
    if np.all(np.isfinite(ct)):
        cov[:ntheta, :ntheta] = ct
    if options.progress:
        how = "emcee" if options.sampler == "emcee" else "importance sampling, else emcee"
        print(f"sampling the posterior ({how})…")
    return sample(
        prob.log_density,
        fit.model.data,
        z0,
        cov,
        sampler_config(options),
        executables=prob.lsq.executables,
        batch_mode="map",  # a compiled loop over the walkers: faster than vmap here (CPU)
        prior_sd=space.prior_sd_z,
        derived=functools.partial(reported_draws, fit, options.seed),
        weigh=functools.partial(weighed_draws, fit, options.seed),
    )


def reported_draws(fit: MapFit, seed: int, draws: np.ndarray) -> ReportedDraws:
    """Every reported quantity of the draws (chain, draw, 12) of z, β drawn given θ with
    keys from ``seed`` (:func:`chekan.fit.reported.posterior_draws`): {name: (chain,
    draw, ...)}, and the pointwise log-likelihood (chain, draw, bins, 2), for the record's
    own holds and bins (:func:`real_part`)."""
    import jax

    from chekan.fit.reported import ReportedDraws, posterior_draws

    C, Dn = draws.shape[:2]
    keys = split_keys(jax.random.PRNGKey(seed), C * Dn)
    flat = real_part(fit.model, posterior_draws(fit, draws.reshape(C * Dn, -1), keys))

    def per_chain(v: np.ndarray) -> np.ndarray:
        return np.asarray(v).reshape(C, Dn, *np.shape(v)[1:])

    lp = None if flat.log_density is None else per_chain(flat.log_density)
    return ReportedDraws(
        {k: per_chain(v) for k, v in flat.quantities.items()}, per_chain(flat.loglik), lp
    )


def weighed_draws(
    fit: MapFit, seed: int, points: np.ndarray, block: int
) -> tuple[np.ndarray, ReportedDraws]:
    """The log-density of ``points`` (n, 12) and every reported quantity there (1, n, ...),
    β drawn given θ, from one evaluation per point (:func:`chekan.joint.derived.draws_fn`):
    the importance path's weights and draws (:mod:`inference.importance_path`). The keys
    of block ``block`` (0, 1, …: the first draws, then each extension) are their own."""
    import jax

    from chekan.fit.reported import ReportedDraws, posterior_draws

    base = jax.random.fold_in(jax.random.PRNGKey(seed), 1 + block)
    keys = split_keys(base, points.shape[0])
    flat = real_part(fit.model, posterior_draws(fit, points, keys))
    assert flat.log_density is not None
    one = ReportedDraws(
        {k: np.asarray(v)[None] for k, v in flat.quantities.items()},
        np.asarray(flat.loglik)[None],
        np.asarray(flat.log_density)[None],
    )
    return np.asarray(flat.log_density, dtype=float), one


#: the draws' quantities per hold (their axis after the draws' one)
PER_HOLD = ("angle_error_arcsec", "hold_offset_pix")


def real_part(model: RecordModel, flat: ReportedDraws) -> ReportedDraws:
    """The draws ``flat`` {name: (draws, ...)} of a padded model (its bucket,
    :mod:`chekan.runtime.padding`) cut back to the record's own holds and bins: the
    padding's holds and bins come after the real ones and carry no data (their angle
    errors and hold offsets are draws from the prior, their log-likelihood 0), so that
    nothing reported, and no stopping rule, sees them."""
    from chekan.fit.reported import ReportedDraws

    H, N = model.n_real_holds, model.n_real_bins
    assert bool(np.all(np.asarray(model.data.hold_mask)[:H])), "real holds come first"
    out = {k: np.asarray(v) for k, v in flat.quantities.items()}
    for k in PER_HOLD:
        out[k] = out[k][:, :H]
    return ReportedDraws(out, np.asarray(flat.loglik)[:, :N], flat.log_density)
