r"""Convergence diagnostics and posterior summaries of (chain, draw, ...) arrays.

R̂ is the rank-normalised split R̂ and ESS the rank-normalised bulk/tail effective sample
sizes of Vehtari et al. (2021), computed as ArviZ computes them but in NumPy
(:mod:`inference.mcmc_stats`: no ArviZ import, ≈ 2 s in a new process). Chains must be
*independent* runs (separate ensembles), not walkers of one ensemble.
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

from collections.abc import Mapping

import numpy as np

from . import mcmc_stats
from .params import flat_element_names

__all__ = ["convergence_report", "ess_bulk", "rhat", "summarize_draws"]


def _elements(x: np.ndarray) -> tuple[tuple[int, ...], np.ndarray]:
    x = np.asarray(x, dtype=float)
    if x.ndim < 2:
        raise ValueError(f"need (chain, draw, ...) draws, got shape {x.shape}")
    shape = x.shape[2:]
    return shape, x.reshape(x.shape[0], x.shape[1], -1)


def rhat(draws: np.ndarray) -> np.ndarray | float:
    """Rank-normalised split R̂ per element of ``draws`` (chain, draw, *shape) → shape."""
    shape, flat = _elements(draws)
    out = np.array([mcmc_stats.rhat_rank(flat[..., i]) for i in range(flat.shape[-1])])
    return float(out[0]) if shape == () else out.reshape(shape)


def ess_bulk(draws: np.ndarray) -> np.ndarray | float:
    """Rank-normalised bulk ESS per element of ``draws`` (chain, draw, *shape) → shape."""
    shape, flat = _elements(draws)
    out = np.array([mcmc_stats.ess_bulk(flat[..., i]) for i in range(flat.shape[-1])])
    return float(out[0]) if shape == () else out.reshape(shape)


def summarize_draws(
    draws: Mapping[str, np.ndarray], hdi_prob: float
) -> dict[str, dict[str, float]]:
    """``{flat_name: {mean, sd, hdi_low, hdi_high, r_hat, ess_bulk, ess_tail, mcse_mean}}``.

    ``draws[name]`` has shape (chain, draw, *shape); flat names follow
    :meth:`inference.ParamSpace.flat_names` (``"b"``, ``"b[2]"``, ``"b[1,0]"``).
    """
    if not 0 < hdi_prob < 1:
        raise ValueError(f"hdi_prob must be in (0, 1), got {hdi_prob}")
    out: dict[str, dict[str, float]] = {}
    for name, x in draws.items():
        shape, flat = _elements(x)
        for i, fname in enumerate(flat_element_names(name, shape)):
            xi = flat[..., i]
            lo, hi = mcmc_stats.hdi(xi, hdi_prob)
            n_total = xi.size
            out[fname] = {
                "mean": float(np.mean(xi)),
                "sd": float(np.std(xi, ddof=1)) if n_total > 1 else float("nan"),
                "hdi_low": lo,
                "hdi_high": hi,
                "r_hat": mcmc_stats.rhat_rank(xi),
                "ess_bulk": mcmc_stats.ess_bulk(xi),
                "ess_tail": mcmc_stats.ess_tail(xi),
                "mcse_mean": mcmc_stats.mcse_mean(xi),
            }
    return out


def convergence_report(
    summary: Mapping[str, Mapping[str, float]], rhat_max: float = 1.01, ess_min: float = 400
) -> tuple[bool, list[str]]:
    """``(ok, problems)``: one loud, human-readable line per element failing R̂ or ESS."""
    problems: list[str] = []
    for name, s in summary.items():
        r, eb = s.get("r_hat", np.nan), s.get("ess_bulk", np.nan)
        et = s.get("ess_tail", np.inf)
        if not np.isfinite(r) or r > rhat_max:
            problems.append(
                f"{name}: R-hat = {r:.4f} > {rhat_max:g}: the independent chains disagree "
                "(not converged or multimodal) — run longer or check identifiability"
            )
        if not np.isfinite(eb) or eb < ess_min:
            problems.append(
                f"{name}: bulk ESS = {eb:.0f} < {ess_min:g}: too few effective draws for a "
                "reliable mean/sd — run longer or reduce the autocorrelation"
            )
        if np.isfinite(et) and et < ess_min:
            problems.append(
                f"{name}: tail ESS = {et:.0f} < {ess_min:g}: interval ends are unreliable"
            )
    return not problems, problems
