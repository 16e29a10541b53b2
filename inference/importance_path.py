r"""The fast path of :func:`inference.sampling.sample`: importance sampling from the fitted
proposal, taken where it is reliable, else emcee runs (the reference).

From the proposal q fitted to the posterior (:func:`inference.proposal.fit_proposal`),
``importance_points`` draws in ``n_chains`` independent batches are weighed by
:math:`\pi/q` and Pareto-smoothed (:mod:`inference.importance`). The path is taken when

.. math::  \hat k < k_\max \;(0.7),\qquad
           \mathrm{ESS}_f \ge \text{target\_ess}\ \text{for every coordinate of } z
           \text{ and every scalar quantity } f \text{ the caller reports},

first on z alone (where the caller gives no ``weigh``, its quantities are computed only
once z passes), with more draws, as many as the least ESS says it needs, while k̂ passes
and an ESS falls short, up to ``importance_max_points``. Where k̂ refuses, the proposal's
Gaussian components are fitted anew to the weighted draws (population Monte Carlo,
:func:`inference.proposal.refit`; up to ``importance_refits`` times) and the draws are
made afresh from it: those of the earlier proposal are not kept. The kept draws are each batch
resampled to equal weights (systematic resampling),
one batch a "chain": their R̂ compares independent batches; their ESS is the importance
sampling's (:func:`inference.importance.quantity_ess`), not that of the resampled draws.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .importance import (
    ImportanceDraws,
    ImportanceVerdict,
    draw_importance,
    extend,
    judge,
    quantity_ess,
    resample,
)
from .proposal import MixtureProposal, refit
from .retained import SamplingResult
from .sampler_config import SamplerConfig

__all__ = ["importance_result", "weighted_ess", "with_weighted_ess"]

#: the tail ESS's quantiles (Vehtari et al. 2021: the 5 % and 95 % indicator functions)
TAIL = (0.05, 0.95)


def importance_result(
    lnp_batched: Callable[[np.ndarray], np.ndarray],
    proposal: MixtureProposal,
    config: SamplerConfig,
    derived: Callable[[np.ndarray], Mapping[str, np.ndarray]] | None,
    t0: float,
    weigh: Callable[[np.ndarray, int], tuple[np.ndarray, Any]] | None = None,
) -> tuple[SamplingResult | None, ImportanceVerdict]:
    """The importance sampling's :class:`SamplingResult` where it is taken (module
    docstring), else None; and its verdict in either case. Its random numbers are its own
    (seeded from ``config.seed``), so that emcee after a refusal runs exactly as alone.
    ``weigh(points, block) → (log-density, derived (1, n, ...))``: both from one
    evaluation (else the log-density now, ``derived`` once z passes)."""
    rng = np.random.default_rng((config.seed, 0x1515))
    blocks: list[Any] = []

    def lnp(points: np.ndarray) -> np.ndarray:
        if weigh is None:
            return lnp_batched(points)
        lp, extra = weigh(points, len(blocks))
        blocks.append(extra)
        return lp

    draws, verdict = _judged_draws(lnp, proposal, config, rng, blocks)
    if not verdict.accepted:
        return None, verdict
    if blocks:
        extra = _joined(blocks)
    else:
        extra = None if derived is None else derived(draws.points[None])
    if extra is not None:
        per_point = {k: np.asarray(v)[0] for k, v in extra.items()}
        refits = verdict.refits
        verdict = judge(
            draws, {**_coordinates(draws), **per_point}, config.khat_max, config.target_ess
        )
        verdict = dataclasses.replace(verdict, refits=refits)
        if not verdict.accepted:
            return None, verdict
    index = resample(draws, draws.points.shape[0] // config.n_chains, rng)
    kept = _taken(extra, index)
    coordinates = _coordinates(draws)  # their ESS is the verdict's (judged above)
    ess = np.array([verdict.ess[name] for name in coordinates])
    result = SamplingResult(
        draws=draws.points[index],
        log_prob=draws.log_density[index],
        blobs=None,
        tau=np.full(draws.points.shape[1], np.nan),
        burn=0,
        thin=1,
        n_steps=0,
        acceptance=np.zeros(0),
        seconds=time.perf_counter() - t0,
        converged=True,
        message=verdict.message,
        ess=ess,
        n_walkers=0,
        derived=kept,
        method="importance",
        importance=verdict,
        weighted_ess=None if extra is None else weighted_ess(per_point, draws.log_weights),
    )
    return result, verdict


def _judged_draws(
    lnp: Callable[[np.ndarray], np.ndarray],
    proposal: MixtureProposal,
    config: SamplerConfig,
    rng: np.random.Generator,
    blocks: list[Any],
) -> tuple[ImportanceDraws, ImportanceVerdict]:
    """The draws and their verdict on z (module docstring): drawn, refitted where k̂
    refuses and the refit changes the proposal (``blocks``, what ``lnp`` keeps of each
    evaluation, emptied with the draws), extended where an ESS falls short."""
    draws = draw_importance(lnp, proposal, config.importance_points, config.n_chains, rng)
    refits = 0
    while True:
        verdict = judge(draws, _coordinates(draws), config.khat_max, config.target_ess)
        verdict = dataclasses.replace(verdict, refits=refits)
        if not verdict.accepted and verdict.khat >= verdict.k_limit:
            if refits >= config.importance_refits:
                return draws, verdict
            weights = np.exp(draws.log_weights)
            new = refit(proposal, draws.points, weights, rng, components=config.proposal_components)
            if new is proposal:  # nothing to refit: fresh draws of the same q would not help
                return draws, verdict
            proposal = new
            blocks.clear()  # what was drawn from the proposal before is not used
            draws = draw_importance(lnp, proposal, config.importance_points, config.n_chains, rng)
            refits += 1
            continue
        short = (
            not verdict.accepted
            and verdict.khat < verdict.k_limit
            and verdict.min_ess < config.target_ess
        )
        n = draws.points.shape[0]
        if not short or n >= config.importance_max_points:
            return draws, verdict
        draws = extend(draws, lnp, proposal, _more(n, verdict.min_ess, config), rng)


def _more(n: int, ess: float, config: SamplerConfig) -> int:
    """How many draws to add to ``n`` whose least ESS is ``ess``: the ESS grows about in
    proportion to the draws, so n(target/ESS − 1), 15 % more for its scatter, at least one
    per batch and no more than ``importance_max_points`` allows."""
    need = n * (config.target_ess / max(ess, 1.0) - 1.0) * 1.15
    return int(min(max(math.ceil(need), config.n_chains), config.importance_max_points - n))


def _joined(blocks: list[Any]) -> Any:
    """The caller's quantities of the blocks drawn (each (1, n, ...)) as one: by their own
    ``joined`` where they have one, else a dict."""
    if len(blocks) == 1:
        return blocks[0]
    if hasattr(blocks[0], "joined"):
        return blocks[0].joined(blocks)
    return {k: np.concatenate([np.asarray(b[k]) for b in blocks], axis=1) for k in blocks[0]}


def _coordinates(draws: ImportanceDraws) -> dict[str, np.ndarray]:
    return {f"z[{i}]": x for i, x in enumerate(draws.points.T)}


def _taken(extra: Any, index: np.ndarray) -> Any:
    """The caller's quantities (1, n, ...) at the resampled draws (chain, draw, ...): by
    their own ``take`` where they have one (a type that carries more than a mapping), else
    a dict."""
    if extra is None:
        return None
    if hasattr(extra, "take"):
        return extra.take(index)
    return {k: np.asarray(v)[0][index] for k, v in extra.items()}


def weighted_ess(
    quantities: Mapping[str, np.ndarray], log_weights: np.ndarray
) -> dict[str, tuple[float, float]]:
    """{name: (bulk ESS, tail ESS)} of each scalar quantity (n,) under the importance
    weights: the bulk one of f, the tail one the smaller of the indicator functions
    1[f ≤ q₀.₀₅] and 1[f ≥ q₀.₉₅] at the weighted quantiles (:data:`TAIL`)."""
    w = np.exp(log_weights - np.max(log_weights))
    w /= w.sum()
    out = {}
    for name, f in quantities.items():
        f = np.asarray(f, dtype=float)
        if f.ndim != 1:
            continue
        order = np.argsort(f)
        cw = np.cumsum(w[order])
        at = [min(int(np.searchsorted(cw, q)), f.size - 1) for q in TAIL]
        lo, hi = float(f[order][at[0]]), float(f[order][at[1]])
        tail = min(
            quantity_ess((f <= lo).astype(float), log_weights),
            quantity_ess((f >= hi).astype(float), log_weights),
        )
        out[name] = (quantity_ess(f, log_weights), tail)
    return out


def with_weighted_ess(
    summary: Mapping[str, Mapping[str, float]], ess: Mapping[str, tuple[float, float]] | None
) -> dict[str, dict[str, float]]:
    """``summary`` (:func:`inference.diagnostics.summarize_draws` of resampled draws) with
    the importance sampling's bulk and tail ESS (``ess``: :func:`weighted_ess`) and the
    mean's Monte Carlo error sd/√ESS in place of the resampled draws' own; unchanged
    without ``ess`` (emcee's draws)."""
    out = {k: dict(v) for k, v in summary.items()}
    for name, (bulk, tail) in (ess or {}).items():
        if name in out:
            row = out[name]
            row.update(ess_bulk=float(bulk), ess_tail=float(tail))
            row["mcse_mean"] = float(row["sd"] / np.sqrt(bulk)) if bulk > 0 else float("inf")
    return out
