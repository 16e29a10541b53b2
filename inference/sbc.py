r"""Simulation-based calibration (SBC) helpers.

If truths :math:`\theta_i \sim p(\theta)` generate data :math:`y_i` and the inference is exact,
then (Talts et al. 2018):

* the rank of :math:`\theta_i` among :math:`L` posterior draws is uniform on {0, …, L};
* a central :math:`q`-interval covers :math:`\theta_i` with probability :math:`q`, so the
  number of covering datasets is Binomial(n, q);
* for Gaussian posteriors, :math:`(\theta_i - \text{mean}_i)/\text{sd}_i \sim N(0, 1)`.

Thresholds are binomial tail bounds at a small ``alpha`` (1e-3), so that a CI test with fixed
seeds fails only for a genuine miscalibration.
"""

from __future__ import annotations

from typing import Any

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike


def _stats():
    from scipy import stats  # lazy: ~1 s of import time

    return stats


__all__ = [
    "binomial_bounds",
    "central_interval",
    "coverage",
    "coverage_table",
    "format_coverage_table",
    "gaussian_interval",
    "rank_statistic",
    "rank_uniformity_pvalue",
    "zscores",
]


def coverage(truth: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> float:
    """Fraction of ``lo ≤ truth ≤ hi`` (element-wise over all entries)."""
    truth, lo, hi = (np.asarray(a, dtype=float) for a in (truth, lo, hi))
    return float(np.mean((lo <= truth) & (truth <= hi)))


def central_interval(
    draws: ArrayLike, prob: float, axis: int = -1
) -> tuple[np.ndarray, np.ndarray]:
    """Equal-tailed ``prob`` interval: the (1∓prob)/2 quantiles of ``draws`` along ``axis``."""
    if not 0 < prob < 1:
        raise ValueError(f"prob must be in (0, 1), got {prob}")
    q = np.quantile(np.asarray(draws, dtype=float), [(1 - prob) / 2, (1 + prob) / 2], axis=axis)
    return q[0], q[1]


def gaussian_interval(mean: ArrayLike, sd: ArrayLike, prob: float) -> tuple[np.ndarray, np.ndarray]:
    """Central ``prob`` interval of N(mean, sd²): mean ∓ Φ⁻¹((1+prob)/2)·sd."""
    k = _stats().norm.ppf(0.5 + prob / 2)
    mean, sd = np.asarray(mean, dtype=float), np.asarray(sd, dtype=float)
    return mean - k * sd, mean + k * sd


def rank_statistic(truth: ArrayLike, draws: ArrayLike, axis: int = -1) -> np.ndarray:
    """Number of draws below the truth (0 … L), per dataset; uniform under calibration."""
    truth = np.asarray(truth, dtype=float)
    draws = np.moveaxis(np.asarray(draws, dtype=float), axis, -1)
    return np.sum(draws < truth[..., None], axis=-1)


def rank_uniformity_pvalue(ranks: ArrayLike, n_draws: int, bins: int = 20) -> float:
    """χ² test p-value that ``ranks`` (0 … n_draws) are uniform, in ``bins`` equal bins."""
    ranks = np.asarray(ranks).reshape(-1)
    bins = min(bins, n_draws + 1)
    edges = np.linspace(0, n_draws + 1, bins + 1)
    counts, _ = np.histogram(ranks, bins=edges)
    expected = ranks.size * np.diff(edges) / (n_draws + 1)
    return float(_stats().chisquare(counts, expected * counts.sum() / expected.sum()).pvalue)


def binomial_bounds(n: int, p: float, alpha: float = 1e-3) -> tuple[float, float]:
    """Fractions ``(lo, hi)`` with P(X/n < lo) ≤ α/2 and P(X/n > hi) ≤ α/2, X ~ Binomial(n, p)."""
    if n < 1:
        raise ValueError(f"n must be ≥ 1, got {n}")
    lo = _stats().binom.ppf(alpha / 2, n, p) / n
    hi = _stats().binom.isf(alpha / 2, n, p) / n
    return float(lo), float(hi)


def zscores(truth: ArrayLike, mean: ArrayLike, sd: ArrayLike) -> np.ndarray:
    """(truth − mean)/sd; ~ N(0, 1) for calibrated Gaussian posteriors."""
    truth, mean, sd = (np.asarray(a, dtype=float) for a in (truth, mean, sd))
    return (truth - mean) / sd


def coverage_table(
    truths: Mapping[str, ArrayLike],
    posterior: Mapping[str, ArrayLike] | tuple[Mapping[str, ArrayLike], Mapping[str, ArrayLike]],
    levels: Sequence[float] = (0.5, 0.9, 0.95),
    alpha: float = 1e-3,
) -> dict[str, dict[str, dict[str, float]]]:
    """Coverage per name and level, with binomial acceptance bounds.

    ``truths[name]`` is (n,) over simulated datasets. ``posterior`` is either draws
    ``{name: (n, L)}`` (central intervals from quantiles) or ``(means, sds)`` with
    ``{name: (n,)}`` each (Gaussian intervals). Returns
    ``{name: {"50%": {coverage, lo, hi, ok}, ..., "z": {mean, sd}}}`` (``z`` for mean/sd only).
    """
    gaussian = isinstance(posterior, tuple)
    out: dict[str, dict[str, dict[str, float]]] = {}
    for name, t in truths.items():
        t = np.asarray(t, dtype=float).reshape(-1)
        n = t.size
        row: dict[str, dict[str, float]] = {}
        for q in levels:
            post: Any = posterior
            if gaussian:
                means, sds = post
                lo_i, hi_i = gaussian_interval(
                    np.reshape(means[name], -1), np.reshape(sds[name], -1), q
                )
            else:
                d = np.asarray(post[name], dtype=float)
                lo_i, hi_i = central_interval(d.reshape(n, -1), q, axis=-1)
            cov = coverage(t, lo_i, hi_i)
            blo, bhi = binomial_bounds(n, q, alpha)
            row[f"{100 * q:g}%"] = {
                "coverage": cov,
                "lo": blo,
                "hi": bhi,
                "ok": float(blo <= cov <= bhi),
            }
        if gaussian:
            pz: Any = posterior
            z = zscores(t, np.reshape(pz[0][name], -1), np.reshape(pz[1][name], -1))
            row["z"] = {"mean": float(np.mean(z)), "sd": float(np.std(z, ddof=1))}
        out[name] = row
    return out


def format_coverage_table(table: Mapping[str, Mapping[str, Mapping[str, float]]]) -> str:
    """Plain-text rendering of :func:`coverage_table` (one line per name)."""
    lines = []
    for name, row in table.items():
        cells = []
        for level, c in row.items():
            if level == "z":
                cells.append(f"z: mean {c['mean']:+.3f} sd {c['sd']:.3f}")
            else:
                flag = "" if c["ok"] else " !!"
                cells.append(f"{level}: {c['coverage']:.3f} [{c['lo']:.3f}, {c['hi']:.3f}]{flag}")
        lines.append(f"{name:>16s}  " + "  ".join(cells))
    return "\n".join(lines)
