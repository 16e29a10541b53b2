"""The draws an ensemble run keeps: burn-in 2τ_max cut, thinned by max(1, ⌊τ_min/2⌋) (and to
at most ``max_draws``), laid out (chain, draw, ndim) walker-major; their bulk ESS and rank R̂
(the stopping rule's), the blobs of the retained draws, and the :class:`SamplingResult`."""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from .autocorr import burn_thin
from .chunks import map_chunks
from .problem import Executables
from .walkers import flatten_walkers

if TYPE_CHECKING:
    from .sampler_config import SamplerConfig

__all__ = [
    "SamplingResult",
    "derived_failure",
    "eval_blobs",
    "retained",
    "retained_diagnostics",
    "sampling_result",
]


@dataclass(frozen=True)
class SamplingResult:
    """Retained posterior draws in z-space and what is needed to judge them.

    ``draws`` (chain, draw, ndim) after burn-in and thinning; ``log_prob`` (chain, draw);
    ``blobs`` per-draw extras from ``blob_fn`` (chain, draw, ...); ``tau`` (ndim,) integrated
    autocorrelation times in steps; ``ess`` (ndim,) the emcee-based estimate used for stopping
    (check with :func:`inference.diagnostics.ess_bulk`); ``acceptance`` (chain,);
    ``seconds`` the whole call (``derived`` included); ``derived``: the caller's quantities
    of the retained draws (:func:`sample`).
    """

    draws: np.ndarray
    log_prob: np.ndarray
    blobs: dict[str, np.ndarray] | None
    tau: np.ndarray
    burn: int
    thin: int
    n_steps: int
    acceptance: np.ndarray
    seconds: float
    converged: bool = False
    message: str = ""
    ess: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_walkers: int = 0
    derived: Mapping[str, np.ndarray] | None = None
    """``derived(draws)`` of :func:`sample` for the retained draws (None without it)."""
    method: str = "emcee"
    """Which sampler made the draws: ``"emcee"``, or ``"importance"`` (the fast path,
    :mod:`inference.importance_path`: then ``tau`` is NaN, ``n_steps`` 0, and each chain is
    one independent batch resampled to equal weights)."""
    importance: Any = None
    """The importance sampling's verdict (:class:`inference.importance.ImportanceVerdict`)
    where it was tried (taken, or refused before emcee ran), else None."""
    weighted_ess: Mapping[str, tuple[float, float]] | None = None
    """The importance path's (bulk, tail) ESS of each scalar quantity of ``derived``: the
    ESS to report (the resampled draws repeat points, and their own ESS would overstate)."""

    @property
    def n_chains(self) -> int:
        return self.draws.shape[0]

    def values(self, space: Any) -> dict[str, np.ndarray]:
        """Draws mapped to named values with ``space.to_values`` → (chain, draw, *shape)."""
        return {k: np.asarray(v) for k, v in space.to_values(self.draws).items()}


def derived_failure(extra: Mapping[str, np.ndarray], config: SamplerConfig) -> str:
    """Which scalar quantity of ``extra`` ((chain, draw) arrays) fails bulk ESS ≥
    ``target_ess`` or rank R̂ ≤ ``rhat_max``, and why; the empty string where none does."""
    from . import mcmc_stats

    for name, x in extra.items():
        x = np.asarray(x)
        if x.ndim != 2 or not np.issubdtype(x.dtype, np.number):
            continue  # not a scalar per draw
        if not np.all(np.isfinite(x)) or np.ptp(x) == 0:
            continue  # a constant has no ESS; non-finite draws are the caller's to report
        ess = mcmc_stats.ess_bulk(x)
        if not ess >= config.target_ess:
            return f"the derived {name} has bulk ESS {ess:.0f} < {config.target_ess:g}"
        rhat = mcmc_stats.rhat_rank(x)
        if not rhat <= config.rhat_max:
            return f"the derived {name} has R̂ {rhat:.3f} > {config.rhat_max:g}"
    return ""


def retained(samplers, tau, n_steps: int, config: SamplerConfig, nw: int):
    """Burn-in, thinning (``max_draws`` applied) and the retained draws (chain, draw, ndim)."""
    burn, thin = burn_thin(tau, n_steps)
    if config.max_draws:
        thin = max(thin, math.ceil(nw * (n_steps - burn) / config.max_draws))
    draws = np.stack([flatten_walkers(s.get_chain()[burn::thin]) for s in samplers])
    return burn, thin, draws


def retained_diagnostics(samplers, tau, n_steps: int, config: SamplerConfig, nw: int):
    """Bulk ESS per coordinate and the largest rank R̂ of the draws that would be retained
    (R̂ only where every ESS reaches ``target_ess``, else ∞: the stopping rule needs both)."""
    from . import mcmc_stats

    _, _, draws = retained(samplers, tau, n_steps, config, nw)
    ess = np.array([mcmc_stats.ess_bulk(draws[..., i]) for i in range(draws.shape[-1])])
    ess = np.where(np.isfinite(ess), ess, 0.0)
    if np.min(ess) < config.target_ess:  # not converged whatever R̂ is: skip its ranks
        return ess, math.inf
    rhat = max(mcmc_stats.rhat_rank(draws[..., i]) for i in range(draws.shape[-1]))
    return ess, float(np.nan_to_num(rhat, nan=np.inf))


def sampling_result(
    samplers,
    n_steps,
    tau,
    ess,
    converged,
    config,
    nw,
    blobs_of,
    data,
    t0,
    why: str = "",
    derived_of: Callable[[np.ndarray], Mapping[str, np.ndarray]] | None = None,
) -> SamplingResult:
    """The retained draws (burn-in cut, thinned), the blobs, the caller's derived quantities
    of them (``derived_of``) and the verdict; ``seconds`` counts from ``t0`` to the end."""
    burn, thin, draws = retained(samplers, tau, n_steps, config, nw)
    log_prob = np.stack([flatten_walkers(s.get_log_prob()[burn::thin]) for s in samplers])
    if converged:
        message = (
            f"converged after {n_steps} steps: tau_max={np.max(tau):.1f}, "
            f"ESS≈{np.min(ess):.0f} ≥ {config.target_ess:g}"
        )
    else:
        message = (
            f"NOT converged: max_steps={config.max_steps} reached with tau_max={np.max(tau):.1f} "
            f"(need ≥ {config.tau_factor:g}·tau = {config.tau_factor * np.max(tau):.0f} steps) "
            f"and ESS≈{np.min(ess):.0f} (target {config.target_ess:g})"
            + (f", and {why}" if why else "")
            + "; the draws are unreliable: run longer, reparametrise, or marginalise linear "
            "parameters"
        )
        warnings.warn(message, RuntimeWarning, stacklevel=3)
    blobs = None if blobs_of is None else blobs_of(draws, data, nw // 2)
    derived = None if derived_of is None else derived_of(draws)
    return SamplingResult(
        draws=draws,
        log_prob=log_prob,
        blobs=blobs,
        tau=tau,
        burn=burn,
        thin=thin,
        n_steps=n_steps,
        acceptance=np.array([np.mean(s.acceptance_fraction) for s in samplers]),
        seconds=time.perf_counter() - t0,
        converged=converged,
        message=message,
        ess=ess,
        n_walkers=nw,
        derived=derived,
    )


def eval_blobs(
    blob_fn: Callable, draws: np.ndarray, data: Any, chunk: int, *, executables: Executables
) -> dict:
    nc, nd, ndim = draws.shape
    flat = draws.reshape(nc * nd, ndim)
    batched = executables.jit("blobs", jax.vmap(blob_fn, in_axes=(0, None)))
    size = max(chunk, min(4096, flat.shape[0]))
    joined = map_chunks(lambda z: batched(z, data), [flat], size, threads=1)
    if not isinstance(joined, Mapping):
        joined = {"blob": joined}
    return {k: np.asarray(v).reshape(nc, nd, *np.shape(v)[1:]) for k, v in joined.items()}
