"""Simulation-based calibration: exact posteriors must cover at the nominal rate."""

from __future__ import annotations

import numpy as np
import pytest

from chekan.runtime.compiler import Compiler
from inference import LeastSquaresProblem, Param, ParamSpace, fit_map_batch, sbc

N_SIM = 300
LEVELS = (0.5, 0.9, 0.95)


def _conjugate_normal(rng: np.random.Generator, n: int = N_SIM, m: int = 5, sigma: float = 0.7):
    """θ ~ N(0, 1); y_j | θ ~ N(θ, σ²), j = 1..m. Posterior: N(Σy/(σ² + m), σ²/(σ² + m))."""
    theta = rng.normal(size=n)
    y = theta[:, None] + sigma * rng.normal(size=(n, m))
    post_var = 1.0 / (1.0 + m / sigma**2)
    post_mean = post_var * y.sum(axis=1) / sigma**2
    return theta, post_mean, np.full(n, np.sqrt(post_var))


def test_exact_gaussian_posteriors_are_calibrated() -> None:
    rng = np.random.default_rng(2024)
    theta, mean, sd = _conjugate_normal(rng)
    table = sbc.coverage_table({"theta": theta}, ({"theta": mean}, {"theta": sd}), LEVELS)
    for level in ("50%", "90%", "95%"):
        assert table["theta"][level]["ok"], sbc.format_coverage_table(table)
    assert abs(table["theta"]["z"]["mean"]) < 4 / np.sqrt(N_SIM)
    # the same with posterior draws: interval coverage and uniform ranks
    draws = mean[:, None] + sd[:, None] * rng.normal(size=(N_SIM, 200))
    table = sbc.coverage_table({"theta": theta}, {"theta": draws}, LEVELS)
    assert all(table["theta"][lv]["ok"] for lv in ("50%", "90%", "95%"))
    ranks = sbc.rank_statistic(theta, draws)
    assert ranks.min() >= 0 and ranks.max() <= 200
    assert sbc.rank_uniformity_pvalue(ranks, 200) > 1e-3


def test_miscalibration_is_detected() -> None:
    """Posterior sd halved: the 90 % interval covers ≈ 59 %, far outside the binomial bounds."""
    rng = np.random.default_rng(7)
    theta, mean, sd = _conjugate_normal(rng)
    table = sbc.coverage_table({"theta": theta}, ({"theta": mean}, {"theta": 0.5 * sd}), LEVELS)
    assert not table["theta"]["90%"]["ok"]
    assert "!!" in sbc.format_coverage_table(table)


def test_helpers() -> None:
    lo, hi = sbc.binomial_bounds(300, 0.9, alpha=1e-3)
    assert 0.83 < lo < 0.9 < hi < 0.96
    assert sbc.coverage([0, 1, 2], [-1, 1.5, 1.5], [1, 2, 3]) == pytest.approx(2 / 3)
    lo, hi = sbc.central_interval(np.arange(101.0), 0.9)
    assert (lo, hi) == (pytest.approx(5.0), pytest.approx(95.0))
    np.testing.assert_allclose(sbc.zscores([1.0, 2.0], [0.0, 0.0], [1.0, 4.0]), [1.0, 0.5])


def test_map_laplace_calibration_over_prior_draws() -> None:
    """Vmapped MAP + Laplace on 300 prior draws of a linear-Gaussian model (Laplace is exact)."""
    rng = np.random.default_rng(5)
    n_obs, sigma = 12, 0.4
    t = np.linspace(-1, 1, n_obs)
    space = ParamSpace([Param("a", scale=1.5), Param("b", loc=0.5, scale=0.8)])
    problem = LeastSquaresProblem(
        space, lambda v, d: (d["y"] - v["a"] - v["b"] * d["t"]) / sigma, Compiler()
    )
    z_true = space.sample_prior_z(rng, N_SIM)
    truth = space.to_values(z_true)
    y = truth["a"][:, None] + truth["b"][:, None] * t + sigma * rng.normal(size=(N_SIM, n_obs))
    res = fit_map_batch(problem, {"t": t, "y": y}, data_axes={"t": None, "y": 0})
    assert res.converged.all()
    table = sbc.coverage_table(truth, (res.values, res.sd), LEVELS)
    for name in ("a", "b"):
        for level in ("50%", "90%", "95%"):
            assert table[name][level]["ok"], sbc.format_coverage_table(table)
        assert 0.8 < table[name]["z"]["sd"] < 1.2
