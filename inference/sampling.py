r"""Posterior sampling with emcee driven by a jitted, vectorised JAX log-density.

The caller supplies :math:`\log p(z\mid \text{data})` up to a constant (prior + likelihood, in
the working coordinates :math:`z`). Several *independent* ensembles ("chains") are run side by
side, so that split-R̂ across chains is meaningful (walkers of one ensemble are not independent).

Stopping rule, checked every ``check_every`` steps with the integrated autocorrelation time
:math:`\tau_k` of each coordinate (emcee's estimator, averaged over chains):

.. math::  n \ge \text{min\_steps},\quad n \ge \text{tau\_factor}\cdot\tau_\max,\quad
           \widehat{\text{ESS}} = \frac{C\,W\,(n - \text{burn})}{\tau_\max} \ge \text{target\_ess},

with burn-in :math:`2\tau_\max` and thinning :math:`\max(1, \lfloor\tau_\min/2\rfloor)`.

Retained draws are laid out ``(chain, draw, ndim)`` with ``draw`` running walker-major (each
walker's thinned trace contiguous), so that autocorrelation-based ESS from ArviZ sees genuine
time series.
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

import dataclasses
import os
import sys
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any, Literal

import emcee
import jax
import numpy as np
from jax import Array
from numpy.typing import ArrayLike

from .autocorr import burn_thin, integrated_time, mean_tau
from .importance_path import importance_result
from .mode import refine_mode
from .moves import IndependenceMove, SnookerMove, moves_for
from .problem import Executables
from .proposal import MixtureProposal, fit_proposal
from .retained import (
    SamplingResult,
    derived_failure,
    eval_blobs,
    retained,
    retained_diagnostics,
    sampling_result,
)
from .sampler_config import SamplerConfig
from .walkers import eval_any, initial_walkers, proposal_walkers, regularised_cov

BatchMode = Literal["vmap", "map"]
Derived = Callable[[np.ndarray], Mapping[str, np.ndarray]]
Weigh = Callable[[np.ndarray, int], tuple[np.ndarray, Mapping[str, np.ndarray]]]

__all__ = [
    "IndependenceMove",
    "SamplerConfig",
    "SamplingResult",
    "SnookerMove",
    "integrated_time",
    "sample",
]


# --------------------------------------------------------------------------- JAX side
def _host_logp(
    log_density: Callable,
    data: Any,
    executables: Executables,
    batch_mode: BatchMode = "vmap",
) -> Callable[[np.ndarray], np.ndarray]:
    if batch_mode == "map":  # a loop over the points, compiled as one function

        def looped(zs, d):
            return jax.lax.map(lambda z: log_density(z, d), zs)

        fn = looped
    else:
        fn = jax.vmap(log_density, in_axes=(0, None))
    # compiled by the caller's compiler, once per batch size (kept across processes by a store)
    batched = executables.jit(f"log_density_{batch_mode}", fn)

    def lnp(zs: np.ndarray) -> np.ndarray:
        # NumPy in, NumPy out: jnp.asarray on the input alone costs ~4x the call itself.
        out = np.asarray(batched(zs, data), dtype=float)
        if out.shape != zs.shape[:1]:  # (checked here, not by tracing it once more)
            raise ValueError(
                f"log_density must return a scalar, returned shape {out.shape[1:]} per point"
            )
        return np.where(np.isfinite(out), out, -np.inf)

    return lnp


# --------------------------------------------------------------------------- public API
def sample(
    log_density: Callable[[Array, Any], Array],
    data: Any,
    z_init: ArrayLike,
    init_cov: ArrayLike,
    config: SamplerConfig | None = None,
    *,
    blob_fn: Callable[[Array, Any], Any] | None = None,
    executables: Executables,
    batch_mode: BatchMode = "vmap",
    prior_sd: ArrayLike | None = None,
    derived: Derived | None = None,
    weigh: Weigh | None = None,
) -> SamplingResult:
    """Sample ``log_density(z, data) -> scalar`` with ``config.n_chains`` emcee ensembles.

    Walkers start from N(``z_init``, ``init_cov``) (e.g. MAP and Laplace covariance; a
    degenerate or non-finite ``init_cov`` is regularised; a vector means variances, a scalar
    an isotropic variance). ``blob_fn(z, data)`` (a pytree of
    arrays, e.g. a dict) is evaluated on the retained draws only. Never raises for lack of
    convergence: ``converged``/``message`` say why and a ``RuntimeWarning`` is emitted.
    ``executables``: the caller's compiler of the log-density (and ``blob_fn``) and keeper
    of what it compiles (a compiler of its own per density, or an executable store whose
    fingerprint covers the code of ``log_density``). ``batch_mode``: how the walkers
    are evaluated together, ``"vmap"`` (vectorised) or ``"map"`` (``jax.lax.map``, a
    compiled loop: on CPU the faster for models whose evaluation holds a factorisation).
    ``prior_sd``: the
    prior's sd of each coordinate of z (inf where flat), for the proposal's shoulders
    (``config.proposal_shoulder_weight``). ``derived``: host-side quantities of the retained
    draws, ``derived(draws (chain, draw, ndim)) → {name: (chain, draw, ...)}`` (what the
    caller reports from them, e.g. functions of z and of further random draws); with
    ``stop_rule="bulk"`` the run stops only when every scalar one ((chain, draw) arrays) also
    has bulk ESS ≥ ``target_ess`` and R̂ ≤ ``rhat_max``, so the rule holds for what is
    reported, not only for z. It is evaluated where z's rule passes (and once at the end if
    the run stops otherwise); its last value is ``SamplingResult.derived``.
    ``config.sampler="auto"``: importance sampling from the fitted proposal where it is
    reliable, else emcee (:mod:`inference.importance_path`); ``weigh(points (n, d), block)
    → (log_density (n,), derived (1, n, ...))``: both from one evaluation per point, for
    that path (else it calls the log-density and ``derived`` apart).
    """
    config = SamplerConfig() if config is None else config
    config.check()
    t0 = time.perf_counter()
    z_init = np.asarray(z_init, dtype=float).reshape(-1)
    ndim = z_init.size
    if ndim == 0 or not np.all(np.isfinite(z_init)):
        raise ValueError(f"z_init must be a non-empty finite vector, got {z_init}")
    nw = config.walkers(ndim)
    data = jax.device_put(data)  # once, not on every call
    lnp = _host_logp(log_density, data, executables, batch_mode)
    lp0 = eval_any(lnp, z_init[None, :], nw // 2)[0]
    if not np.isfinite(lp0):
        raise ValueError("log_density(z_init) is not finite: start from a point in the support")

    rng = np.random.default_rng(config.seed)
    psd = None if prior_sd is None else np.asarray(prior_sd, dtype=float).reshape(ndim)
    cov0 = regularised_cov(init_cov, ndim)
    lnp_batched = partial(eval_any, lnp, batch=nw // 2)  # at the compiled half-batch size
    start, cov, fitted = _proposal(lnp_batched, z_init, cov0, config, rng, psd)
    verdict = None
    if config.sampler == "auto" and fitted is not None:  # the fast path, where it is reliable
        fast, verdict = importance_result(lnp_batched, fitted, config, derived, t0, weigh)
        if fast is not None:
            if blob_fn is not None:
                blobs = eval_blobs(blob_fn, fast.draws, data, nw // 2, executables=executables)
                fast = dataclasses.replace(fast, blobs=blobs)
            return fast
        if config.progress:
            print(f"{verdict.message}: running emcee")
    samplers, states = _ensembles(lnp, lnp_batched, start, cov, fitted, nw, config, rng)
    n_steps, tau, ess, converged, extra, why = _run(samplers, states, config, nw, derived)
    blobs_of = None if blob_fn is None else partial(eval_blobs, blob_fn, executables=executables)
    if derived is None:
        derived_of = None
    else:  # the last check's value where it evaluated them, else of the retained draws
        derived_of = derived if extra is None else (lambda _draws: extra)
    out = sampling_result(
        samplers, n_steps, tau, ess, converged, config, nw, blobs_of, data, t0, why, derived_of
    )
    return out if verdict is None else dataclasses.replace(out, importance=verdict)


def _proposal(
    lnp_batched: Callable,
    z_init: np.ndarray,
    cov: np.ndarray,
    config: SamplerConfig,
    rng,
    prior_sd: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, MixtureProposal | None]:
    """Where the independence moves start and what they propose: the refined mode and its
    Laplace covariance (``"de-independence"``, ``"adaptive-independence"``), and for the
    latter the proposal fitted by importance sampling (else None)."""
    if config.moves not in ("de-independence", "adaptive-independence"):
        return z_init, cov, None
    start, cov, _info = refine_mode(lnp_batched, z_init, cov)
    if config.moves != "adaptive-independence":
        return start, cov, None
    fitted, _x, _lp, _info = fit_proposal(
        lnp_batched,
        start,
        cov * config.proposal_scale**2,
        rng,
        n_points=config.proposal_points,
        components=config.proposal_components,
        df=config.proposal_df,
        alpha=config.proposal_alpha,
        tail_scale=config.proposal_tail_scale,
        tail_df=config.proposal_tail_df,
        prior_sd=prior_sd,
        shoulder_weight=config.proposal_shoulder_weight,
        shoulder_ratio=config.proposal_shoulder_ratio,
    )
    return start, cov, fitted


def _ensembles(
    lnp: Callable,
    lnp_batched: Callable,
    start: np.ndarray,
    cov: np.ndarray,
    fitted: MixtureProposal | None,
    nw: int,
    config: SamplerConfig,
    rng,
) -> tuple[list[emcee.EnsembleSampler], list[emcee.State]]:
    """``config.n_chains`` emcee ensembles and their start (for the independence moves,
    from the refined mode and its covariance, or as draws of the fitted proposal)."""
    ndim = start.size
    lnp_sampler = (
        lnp if config.moves not in ("de-independence", "adaptive-independence") else lnp_batched
    )
    proposal: Any = None
    if config.moves == "de-independence":
        proposal = (start, cov * config.proposal_scale**2)
    if fitted is not None:
        proposal = fitted
    samplers, states = [], []
    for _ in range(config.n_chains):
        if fitted is not None:  # walkers start as draws of the fitted proposal
            coords, lp = proposal_walkers(lnp, fitted, nw, rng)
        else:
            coords, lp = initial_walkers(lnp, start, cov, nw, rng)
        rs = np.random.RandomState(rng.integers(2**31 - 1))
        moves = moves_for(config.moves, proposal, config.proposal_df, config.de_weight)
        samplers.append(emcee.EnsembleSampler(nw, ndim, lnp_sampler, moves=moves, vectorize=True))
        states.append(emcee.State(coords, log_prob=lp, random_state=rs.get_state()))
    return samplers, states


def _run(
    samplers: list[emcee.EnsembleSampler],
    states: list[emcee.State],
    config: SamplerConfig,
    nw: int,
    derived: Derived | None = None,
) -> tuple[int, np.ndarray, np.ndarray, bool, Mapping[str, np.ndarray] | None, str]:
    """Advance the ensembles ``check_every`` steps at a time (in threads) until converged
    or ``max_steps``: ``(steps, τ, ESS, converged, the derived quantities of the final
    draws where the last check evaluated them or None, which derived quantity failed the
    rule at the last check or "")``."""
    from tqdm.auto import tqdm

    nc, ndim = len(samplers), samplers[0].ndim
    show = config.progress and sys.stderr.isatty()
    bar = tqdm(total=config.max_steps, disable=not show, desc="emcee", unit="step")
    n_steps, burn, converged = 0, 0, False
    tau, ess = np.full(ndim, np.nan), np.zeros(ndim)
    extra: Mapping[str, np.ndarray] | None = None
    why = ""  # (both set again after every advance)
    workers = config.threads or min(nc, os.cpu_count() or 1)
    pool = ThreadPoolExecutor(workers, thread_name_prefix="ensemble") if workers > 1 else None
    try:
        while n_steps < config.max_steps:
            k = min(config.check_every, config.max_steps - n_steps)
            work = [(samplers[c], states[c], k, n_steps > 0) for c in range(nc)]
            states = list(pool.map(_advance, work) if pool else map(_advance, work))
            n_steps += k
            bar.update(k)
            extra, why = None, ""  # what the rule says of these draws, not of earlier ones
            chains = [s.get_chain() for s in samplers]
            tau = mean_tau(chains, discard=min(burn, n_steps // 2))
            burn, _ = burn_thin(tau, n_steps)
            ess = nc * nw * (n_steps - burn) / tau
            long_enough = n_steps >= config.min_steps and n_steps >= config.tau_factor * float(
                np.max(tau)
            )
            if config.stop_rule == "bulk" and long_enough:
                ess, rhat = retained_diagnostics(samplers, tau, n_steps, config, nw)
                converged = float(np.min(ess)) >= config.target_ess and rhat <= config.rhat_max
                if converged and derived is not None:
                    extra = derived(retained(samplers, tau, n_steps, config, nw)[2])
                    why = derived_failure(extra, config)
                    converged = not why
            else:
                converged = long_enough and float(np.min(ess)) >= config.target_ess
            bar.set_postfix(tau_max=f"{np.max(tau):.0f}", ess=f"{np.min(ess):.0f}")
            if converged:
                break
    finally:
        bar.close()
        if pool is not None:
            pool.shutdown()
    return n_steps, tau, ess, converged, extra, why


def _advance(job: tuple[emcee.EnsembleSampler, emcee.State, int, bool]) -> emcee.State:
    """``k`` more steps of one ensemble from its state (a job for the thread pool)."""
    sampler, state, k, started = job
    return sampler.run_mcmc(state, k, progress=False, skip_initial_state_check=started)
