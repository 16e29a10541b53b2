r"""An independence proposal fitted to the posterior by importance sampling.

The t proposal at the Laplace approximation, :math:`q_0 = t_\nu(\hat z, s^2\Sigma)`, is good in
the directions where the posterior is Gaussian and poor where it is skewed (a log noise
scale whose likelihood flattens at small values): there the independence sampler rejects
and its τ grows. So :func:`fit_proposal` draws :math:`x_i \sim q_0`, weights them by
:math:`w_i \propto \pi(x_i)/q_0(x_i)` (self-normalised importance sampling) and fits a
mixture of :math:`K` Gaussians to the weighted points by EM,

.. math::  r_{ik} \propto \pi_k N(x_i; \mu_k, \Sigma_k),\quad
           \pi_k \propto \sum_i w_i r_{ik},\quad
           \mu_k = \frac{\sum_i w_i r_{ik} x_i}{\sum_i w_i r_{ik}},\quad
           \Sigma_k = \frac{\sum_i w_i r_{ik}(x_i-\mu_k)(x_i-\mu_k)^\top}{\sum_i w_i r_{ik}}
                      + \lambda\,\mathrm{diag}\,\Sigma,

with the component covariances inflated by :math:`c^2` and the start, widened
(:math:`\tilde q_0`: covariance × ``tail_scale``², ``tail_df`` degrees of freedom), as a
*defensive* component of weight :math:`\alpha` (Hesterberg 1995):
:math:`q = \alpha \tilde q_0 + (1-\alpha)\sum_k \pi_k N(\mu_k, c^2\Sigma_k)`, so
:math:`\pi/q \le \pi/(\alpha \tilde q_0)`: the tails stay covered. The sampler's target
is unchanged (the proposal only sets the acceptance rate).
:class:`inference.moves.MixtureIndependenceMove` takes the mixture.

**Shoulders.** Where the data inform a coordinate only weakly (its Laplace sd at least
``shoulder_ratio`` of its prior sd), the posterior can carry a *shoulder* that follows the
prior far beyond the Laplace scale: a hyperparameter whose likelihood flattens as it goes
to zero (a noise scale, an error term) keeps the prior's tail there. No fit from draws
near the mode finds it, and a walker that reaches it waits for a proposal there (an
expected 10⁴–10⁵ steps, measured). For each such coordinate i a further defensive
component :math:`t(\hat z, \tilde\Sigma_i)`, :math:`\tilde\Sigma_i` = the widened start
with its i-th variance raised to the prior's, takes a share of ``shoulder_weight``: then
:math:`\pi/q` stays bounded on the shoulder too.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["MixtureProposal", "fit_proposal", "refit"]

_LOG_2PI = float(np.log(2.0 * np.pi))


def _t_logpdf(x: np.ndarray, mean: np.ndarray, chol: np.ndarray, df: float) -> np.ndarray:
    d = mean.size
    u = np.linalg.solve(chol, (x - mean).T)
    m = np.sum(u * u, axis=0)
    c = math.lgamma((df + d) / 2) - math.lgamma(df / 2) - 0.5 * d * math.log(df * math.pi)
    return c - np.sum(np.log(np.diag(chol))) - 0.5 * (df + d) * np.log1p(m / df)


def _normal_logpdf(x: np.ndarray, mean: np.ndarray, chol: np.ndarray) -> np.ndarray:
    u = np.linalg.solve(chol, (x - mean).T)
    return -0.5 * (np.sum(u * u, axis=0) + mean.size * _LOG_2PI) - np.sum(np.log(np.diag(chol)))


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    return np.squeeze(m, axis) + np.log(np.sum(np.exp(a - m), axis=axis))


@dataclass(frozen=True)
class MixtureProposal:
    """q(x) = α t_ν(x; m₀, L₀L₀ᵀ) + Σₛ βₛ t_ν(x; m₀, LₛLₛᵀ) + (1 − α − Σβ) Σₖ πₖ N(x; μₖ, LₖLₖᵀ),
    normalised densities (the shoulders s: module docstring)."""

    mean0: np.ndarray
    chol0: np.ndarray
    df: float
    alpha: float
    weights: np.ndarray  # (K,) πₖ, summing to 1
    means: np.ndarray  # (K, d)
    chols: np.ndarray  # (K, d, d) lower Cholesky factors
    shoulder_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (S,)
    shoulder_chols: np.ndarray | None = None  # (S, d, d): t_ν(m₀, ·) like the start

    @classmethod
    def t_only(cls, mean: np.ndarray, cov: np.ndarray, df: float) -> MixtureProposal:
        """The plain t proposal (α = 1, no components)."""
        d = np.asarray(mean).size
        return cls(
            np.asarray(mean, float),
            np.linalg.cholesky(np.asarray(cov, float)),
            float(df),
            1.0,
            np.zeros(0),
            np.zeros((0, d)),
            np.zeros((0, d, d)),
        )

    def log_q(self, x: np.ndarray) -> np.ndarray:
        """log q at the rows of ``x`` (n, d)."""
        x = np.atleast_2d(x)
        parts = [np.log(self.alpha) + _t_logpdf(x, self.mean0, self.chol0, self.df)]
        for w, c in self._shoulders():
            parts.append(np.log(w) + _t_logpdf(x, self.mean0, c, self.df))
        rest = 1.0 - self.alpha - float(np.sum(self.shoulder_weights))
        if rest > 0.0:
            for w, m, c in zip(self.weights, self.means, self.chols, strict=True):
                parts.append(np.log(rest * w) + _normal_logpdf(x, m, c))
        return _logsumexp(np.stack(parts), axis=0)

    def _shoulders(self) -> list[tuple[float, np.ndarray]]:
        if self.shoulder_chols is None:
            return []
        return list(zip(self.shoulder_weights.tolist(), self.shoulder_chols, strict=True))

    def sample(self, n: int, random) -> np.ndarray:
        """``n`` draws; ``random``: a ``numpy.random.RandomState`` (emcee's) or ``Generator``."""
        d = self.mean0.size
        rand = getattr(random, "random", None) or random.rand
        u = np.asarray(rand(n))
        normals = np.asarray(random.standard_normal((n, d)))
        chi2 = np.asarray(random.chisquare(self.df, size=n))
        t_scale = np.sqrt(self.df / chi2)[:, None]
        x = self.mean0 + (normals @ self.chol0.T) * t_scale
        lo = self.alpha
        for w, c in self._shoulders():  # the same normals and χ², another factor
            sel = (u >= lo) & (u < lo + w)
            if sel.any():
                x[sel] = self.mean0 + (normals[sel] @ c.T) * t_scale[sel]
            lo += w
        if lo < 1.0:
            edges = lo + (1.0 - lo) * np.cumsum(self.weights)
            comp = np.searchsorted(edges[:-1], u, side="right")
            mix = u >= lo
            for k in range(self.weights.size):
                sel = mix & (comp == k)
                if sel.any():
                    x[sel] = self.means[k] + normals[sel] @ self.chols[k].T
        return x


def _weighted_em(
    x: np.ndarray, w: np.ndarray, k: int, rng: np.random.Generator, iters: int, shrink: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted EM for a K-component Gaussian mixture: (πₖ, μₖ, Σₖ)."""
    n, d = x.shape
    mean = w @ x
    cov = (x - mean).T @ ((x - mean) * w[:, None])
    reg = shrink * np.diag(np.diag(cov))
    # start: K points drawn by weight, every point to its nearest (in the overall metric)
    ci = np.linalg.cholesky(cov + reg)
    y = np.linalg.solve(ci, (x - mean).T).T
    centres = y[rng.choice(n, size=k, replace=False, p=w)]
    d2 = ((y[:, None, :] - centres[None]) ** 2).sum(axis=2)
    resp = np.zeros((n, k))
    resp[np.arange(n), np.argmin(d2, axis=1)] = 1.0
    pis, mus, covs = np.ones(k) / k, np.zeros((k, d)), np.zeros((k, d, d))
    for _ in range(iters):
        nk = np.maximum(w @ resp, 1e-12)
        pis = nk / nk.sum()
        mus = (resp * w[:, None]).T @ x / nk[:, None]
        for j in range(k):
            dx = x - mus[j]
            covs[j] = dx.T @ (dx * (w * resp[:, j])[:, None]) / nk[j] + reg
        logp = np.stack(
            [
                np.log(pis[j]) + _normal_logpdf(x, mus[j], np.linalg.cholesky(covs[j]))
                for j in range(k)
            ],
            axis=1,
        )
        new = np.exp(logp - _logsumexp(logp, axis=1)[:, None])
        if np.max(np.abs(new - resp)) < 1e-6:
            resp = new
            break
        resp = new
    return pis, mus, covs


def fit_proposal(
    log_density: Callable[[np.ndarray], np.ndarray],
    mean: np.ndarray,
    cov: np.ndarray,
    rng: np.random.Generator,
    *,
    n_points: int = 1024,
    components: int = 3,
    df: float = 5.0,
    alpha: float = 0.15,
    inflate: float = 1.1,
    shrink: float = 0.01,
    em_iters: int = 100,
    tail_scale: float = 1.0,
    tail_df: float | None = None,
    prior_sd: np.ndarray | None = None,
    shoulder_weight: float = 0.0,
    shoulder_ratio: float = 0.1,
) -> tuple[MixtureProposal, np.ndarray, np.ndarray, dict]:
    """Fit the mixture proposal (module docstring) from ``n_points`` draws of the t start
    ``t_df(mean, cov)``. ``log_density``: (n, d) → (n,), −inf outside the support.

    ``tail_scale``, ``tail_df``: the defensive component is the start widened (covariance
    × ``tail_scale``², ``tail_df`` degrees of freedom, default ``df``), so that it covers a
    tail the start and the fitted Gaussians miss. Returns ``(proposal, points,
    log_density(points), info)``; ``info["ess_fraction"]``:
    the importance sampling's effective fraction (Σw)²/(nΣw²) of the start, a measure of
    how far the Laplace approximation was from the posterior; ``info["shoulders"]``: the
    coordinates given a shoulder.

    ``prior_sd`` (d,), the prior's sd per coordinate (inf: flat), with ``shoulder_weight``
    > 0: a shoulder component for every coordinate whose sd in ``cov`` is at least
    ``shoulder_ratio`` of the prior's (module docstring), sharing ``shoulder_weight``.
    """
    q0 = MixtureProposal.t_only(mean, cov, df)
    x = q0.sample(n_points, rng)
    lp = np.asarray(log_density(x), float)
    logw = np.where(np.isfinite(lp), lp - q0.log_q(x), -np.inf)
    w = np.exp(logw - np.max(logw))
    w /= w.sum()
    ess_fraction = float(1.0 / (n_points * np.sum(w * w)))
    info = {"ess_fraction": ess_fraction, "n_points": n_points, "shoulders": []}
    keep = w > 0
    if np.count_nonzero(keep) < 10 * components:  # too few points carry weight: keep q₀
        return q0, x, lp, info
    pis, mus, chols = _components(x[keep], w[keep], components, rng, em_iters, shrink, inflate)
    tdf = q0.df if tail_df is None else float(tail_df)
    tail_cov = np.asarray(cov, float) * tail_scale**2
    weak = _weak(np.asarray(cov, float), prior_sd, shoulder_ratio) if shoulder_weight > 0 else []
    info["shoulders"] = weak
    s_chols = None
    if weak and prior_sd is not None:
        s_chols = np.stack([_shoulder_chol(tail_cov, i, prior_sd) for i in weak])
    s_w = np.full(len(weak), shoulder_weight / max(len(weak), 1))
    prop = MixtureProposal(
        q0.mean0, q0.chol0 * tail_scale, tdf, alpha, pis, mus, chols, s_w, s_chols
    )
    return prop, x, lp, info


def refit(
    proposal: MixtureProposal,
    x: np.ndarray,
    w: np.ndarray,
    rng: np.random.Generator,
    *,
    components: int = 3,
    inflate: float = 1.1,
    shrink: float = 0.01,
    em_iters: int = 100,
) -> MixtureProposal:
    """``proposal`` with its Gaussian components fitted anew (weighted EM, as
    :func:`fit_proposal`) to the points ``x`` (n, d) weighted by ``w`` (n,) towards the
    posterior, its defensive and shoulder components kept: population Monte Carlo's step,
    for draws whose weights found mass where the proposal was thin. Unchanged (the same
    object) where fewer than 10 points per component carry weight, or where the proposal
    gives its Gaussian components no weight (:meth:`MixtureProposal.t_only`)."""
    w = np.asarray(w, float)
    keep = np.isfinite(w) & (w > 0)
    rest = 1.0 - proposal.alpha - float(np.sum(proposal.shoulder_weights))
    if rest <= 0.0 or np.count_nonzero(keep) < 10 * components:
        return proposal
    wk = w[keep] / np.sum(w[keep])
    pis, mus, chols = _components(x[keep], wk, components, rng, em_iters, shrink, inflate)
    return dataclasses.replace(proposal, weights=pis, means=mus, chols=chols)


def _components(x, w, k: int, rng, iters: int, shrink: float, inflate: float):
    """(πₖ, μₖ, Lₖ) of the mixture fitted to the weighted points, covariances × inflate²."""
    pis, mus, covs = _weighted_em(x, w, k, rng, iters, shrink)
    return pis, mus, np.stack([np.linalg.cholesky(c * inflate**2) for c in covs])


def _weak(cov: np.ndarray, prior_sd: np.ndarray | None, ratio: float) -> list[int]:
    """Coordinates whose sd in ``cov`` is at least ``ratio`` of the prior's (finite) sd."""
    if prior_sd is None:
        return []
    sd, prior = np.sqrt(np.diag(cov)), np.asarray(prior_sd, float)
    return [int(i) for i in np.flatnonzero(np.isfinite(prior) & (sd >= ratio * prior))]


def _shoulder_chol(cov: np.ndarray, i: int, prior_sd: np.ndarray) -> np.ndarray:
    """Cholesky factor of ``cov`` with its i-th variance raised to the prior's (Σ + c eᵢeᵢᵀ)."""
    c = np.array(cov, float)
    c[i, i] += max(float(prior_sd[i]) ** 2 - c[i, i], 0.0)
    return np.linalg.cholesky(c)
