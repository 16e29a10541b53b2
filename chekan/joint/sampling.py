"""``--method bayes``: emcee on the 12-dimensional marginal posterior p(θ, h | y).

The MAP is refined to the marginal mode and its Laplace approximation
(:func:`inference.mode.refine_mode`, inside :func:`inference.sampling.sample`), which seeds
the walkers and an independence-MH t proposal mixed with DE moves (:func:`sampler_config`);
four independent ensembles for R-hat, burn-in and thinning from the integrated
autocorrelation time. The draws of θ and h are returned; derived quantities follow in
:func:`chekan.joint.derived.posterior_draws`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from chekan.joint.engine import problem_for
from chekan.joint.map import MapFit
from chekan.options import CalibrationOptions


def sampler_config(options: CalibrationOptions, **overrides):
    """The sampler settings of ``--method bayes``.

    Four independent ensembles (for R̂) of 26 walkers; independence MH (0.7) with a t
    proposal at the Laplace approximation of the marginal posterior (hyperparameters
    included) + DE (0.3), whose τ on this posterior is a few steps (DE alone: ~40–90).
    Stop at ≥ 200 steps, ≥ 25 τ and emcee's ESS estimate ≥ 1000 (bulk ESS ≥ 400 per
    parameter with margin); keep ≤ 2000 draws per chain (1000 left the tail ESS of the
    hyperparameters near 400 on 3 h records).
    """
    from inference.sampling import SamplerConfig

    kw: dict[str, Any] = {
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


def sample_posterior(fit: MapFit, options: CalibrationOptions):
    """Draws of (θ, h) from the marginal posterior, started at the MAP (a ``Samples``)."""
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
        print("sampling the posterior (emcee, 4 independent ensembles)…")
    return sample(
        prob.log_density,
        fit.model.data,
        z0,
        cov,
        sampler_config(options),
        executables=prob.lsq.executables,
        batch_mode="map",  # a compiled loop over the walkers: faster than vmap here (CPU)
    )
