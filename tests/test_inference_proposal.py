"""The fitted independence proposal, the bulk-ESS stopping rule and the NumPy R̂/ESS/HDI."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from chekan.runtime.compiler import Compiler
from inference import SamplerConfig, sample, summarize_draws
from inference.proposal import MixtureProposal, fit_proposal


def _banana_t(z, data):
    """Curved in (u, v), heavy-tailed (t₆) in w: far from the Laplace approximation."""
    import jax.numpy as jnp

    u, v, w = z[0], z[1], z[2]
    return -0.5 * u**2 - 0.5 * (v - 0.5 * u**2) ** 2 - 3.5 * jnp.log1p(w**2 / 6.0)


def test_mcmc_stats_equal_arviz() -> None:
    """rank R̂, bulk and tail ESS, MCSE and HDI as ArviZ 0.23 computes them (round-off)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az
    from scipy.fftpack import next_fast_len

    from inference import mcmc_stats as ms

    assert all(ms._next_fast_len(n) == next_fast_len(n) for n in range(1, 3000, 7))
    rng = np.random.default_rng(1)
    for trial in range(24):
        C, D = int(rng.integers(1, 6)), int(rng.integers(4, 500))
        x = rng.standard_normal((C, D))
        if trial % 3 == 0:  # autocorrelated
            for t in range(1, D):
                x[:, t] = 0.9 * x[:, t - 1] + x[:, t]
        if trial % 4 == 0:  # ties
            x = np.round(x, 1)
        pairs = [
            (ms.ess_bulk(x), az.ess(x, method="bulk")),
            (ms.ess_tail(x), az.ess(x, method="tail")),
            (ms.mcse_mean(x), az.mcse(x, method="mean")),
            (ms.hdi(x, 0.95), az.hdi(x.reshape(-1), hdi_prob=0.95)),
        ]
        if C >= 2:
            pairs.append((ms.rhat_rank(x), az.rhat(x, method="rank")))
        for ours, ref in pairs:
            np.testing.assert_allclose(ours, np.asarray(ref, float), rtol=1e-12)


def test_mixture_proposal_density_and_draws() -> None:
    from scipy import stats

    mean, cov = np.array([1.0, -2.0]), np.array([[2.0, 0.3], [0.3, 0.5]])
    q0 = MixtureProposal.t_only(mean, cov, 4.0)
    x = np.array([[0.0, 0.0], [3.0, -1.0]])
    ref = stats.multivariate_t(mean, cov, df=4.0)
    np.testing.assert_allclose(q0.log_q(x), ref.logpdf(x), rtol=1e-12)
    # a mixture: normalised (grid integral) and its draws follow it (moments)
    q = MixtureProposal(
        q0.mean0,
        q0.chol0,
        4.0,
        0.2,
        np.array([0.3, 0.7]),
        np.array([[0.0, 0.0], [2.0, -1.0]]),
        np.stack([np.eye(2) * 0.5, np.linalg.cholesky(np.array([[1.0, 0.4], [0.4, 0.8]]))]),
    )
    g = np.linspace(-25, 25, 801)
    xx = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    assert np.exp(q.log_q(xx)).sum() * (g[1] - g[0]) ** 2 == pytest.approx(1.0, abs=2e-3)
    d = q.sample(200_000, np.random.default_rng(0))
    want = 0.2 * mean + 0.8 * (0.3 * np.array([0.0, 0.0]) + 0.7 * np.array([2.0, -1.0]))
    np.testing.assert_allclose(d.mean(axis=0), want, atol=0.02)


def test_fit_proposal_moves_towards_the_posterior() -> None:
    """From a poor Laplace start (wrong mean and scale), the fitted mixture puts its mass
    where the target is: the importance weights of its own draws are far more even."""

    def logp(x):
        return -0.5 * np.sum(((x - [1.0, -0.5]) / [0.5, 2.0]) ** 2, axis=1)

    rng = np.random.default_rng(2)
    q, x, lp, info = fit_proposal(logp, np.zeros(2), np.eye(2), rng, n_points=2048)
    assert info["ess_fraction"] < 0.6
    np.testing.assert_allclose(lp, logp(x))
    y = q.sample(4096, rng)
    w = np.exp(logp(y) - q.log_q(y))
    assert (w.sum() ** 2 / (w.size * np.sum(w * w))) > 0.8


def test_adaptive_independence_samples_a_non_gaussian_target() -> None:
    cfg = SamplerConfig(
        n_chains=4,
        moves="adaptive-independence",
        proposal_scale=1.0,
        proposal_alpha=0.3,
        proposal_tail_scale=1.5,
        proposal_tail_df=3.0,
        de_weight=0.2,
        stop_rule="bulk",
        target_ess=1000,
        min_steps=0,
        tau_factor=10,
        check_every=5,
        progress=False,
        seed=3,
    )
    res = sample(_banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, executables=Compiler())
    assert res.converged, res.message
    assert res.tau.max() < 8
    flat = res.draws.reshape(-1, 3)
    summ = summarize_draws({"x": res.draws}, hdi_prob=0.9)
    for i, (mean, var) in enumerate(((0.0, 1.0), (0.5, 1.5), (0.0, 1.5))):
        ess = summ[f"x[{i}]"]["ess_bulk"]
        assert ess >= 1000 and summ[f"x[{i}]"]["r_hat"] <= 1.01
        assert abs(flat[:, i].mean() - mean) < 4 * np.sqrt(var / ess), i
        assert abs(flat[:, i].var() / var - 1) < 0.15, (i, flat[:, i].var())
    # the same draws whether the ensembles advance in one thread or several
    cfg.threads = 1
    again = sample(_banana_t, None, np.zeros(3), np.eye(3) * 0.1, cfg, executables=Compiler())
    np.testing.assert_array_equal(again.draws, res.draws)


def test_shoulders_cover_a_prior_shaped_tail() -> None:
    """A weakly informed coordinate whose posterior keeps 3 % of its mass on the prior's
    scale (a shoulder 10× the Laplace sd): without shoulder components the importance
    ratio π/q of the target's own draws reaches > 50× its mean (a walker there waits
    that many steps); with them it stays within 2×, and q is still a normalised density.
    A well-informed coordinate (sd 1 against a prior sd of 100) gets no shoulder."""
    from scipy import stats

    def logp(x):
        core = np.log(0.97) + stats.norm.logpdf(x[:, 1], 0, 0.3)
        tail = np.log(0.03) + stats.norm.logpdf(x[:, 1], 0, 3.0)
        return stats.norm.logpdf(x[:, 0]) + np.logaddexp(core, tail)

    rng = np.random.default_rng(0)
    n = 20_000
    wide = rng.random(n) >= 0.97
    target = np.c_[rng.standard_normal(n), np.where(wide, 3.0, 0.3) * rng.standard_normal(n)]
    g = np.linspace(-40, 40, 1601)
    grid = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    worst = {}
    for weight in (0.0, 0.1):
        q, _, _, info = fit_proposal(
            logp,
            np.zeros(2),
            np.diag([1.0, 0.16]),  # Laplace sd 0.4: above a tenth of the prior's 3
            np.random.default_rng(1),
            components=1,
            alpha=0.1,
            tail_scale=1.2,
            tail_df=3.0,
            prior_sd=np.array([100.0, 3.0]),
            shoulder_weight=weight,
        )
        assert info["shoulders"] == ([1] if weight else [])
        assert np.exp(q.log_q(grid)).sum() * (g[1] - g[0]) ** 2 == pytest.approx(1.0, abs=1e-3)
        w = np.exp(logp(target) - q.log_q(target))
        worst[weight] = w.max() / w.mean()
        draws = q.sample(400_000, np.random.default_rng(2))  # the draws follow q
        share = np.mean(np.abs(draws[:, 1]) > 2.0)
        want = np.sum(np.exp(q.log_q(grid))[np.abs(grid[:, 1]) > 2.0]) * (g[1] - g[0]) ** 2
        assert share == pytest.approx(want, rel=0.05)
    assert worst[0.0] > 50 and worst[0.1] < 2
