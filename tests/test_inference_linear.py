"""Linear-Gaussian marginalisation against the dense formulas."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.stats import multivariate_normal

from inference import conditional_beta, draw_beta, marginal_loglik

dense_logpdf = jax.jit(multivariate_normal.logpdf)


def _case(seed: int = 0, n: int = 15, p: int = 4):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, p))
    noise_var = rng.uniform(0.2, 2.0, n)
    prior_mean = rng.normal(size=p)
    prior_var = rng.uniform(0.1, 10.0, p)
    resid = rng.normal(size=n) * 2
    return resid, A, noise_var, prior_mean, prior_var


def _dense_posterior(resid, A, noise_var, prior_mean, prior_var):
    precision = np.diag(1 / prior_var) + A.T @ (A / noise_var[:, None])
    cov = np.linalg.inv(precision)
    mean = cov @ (prior_mean / prior_var + A.T @ (resid / noise_var))
    return mean, cov


def test_marginal_loglik_matches_dense_gaussian() -> None:
    resid, A, nv, m0, pv = _case()
    dense = dense_logpdf(resid, A @ m0, np.diag(nv) + A @ np.diag(pv) @ A.T)
    got = jax.jit(marginal_loglik)(resid, A, nv, m0, pv)
    assert float(got) == pytest.approx(float(dense), abs=1e-9)


def test_mask_drops_rows_exactly_and_keeps_gradients_finite() -> None:
    resid, A, nv, m0, pv = _case(1)
    keep = np.ones(resid.size, bool)
    keep[-4:] = False
    padded_resid = np.where(keep, resid, 1e30)
    padded_nv = np.where(keep, nv, np.inf)
    dense = dense_logpdf(
        resid[keep], A[keep] @ m0, np.diag(nv[keep]) + A[keep] @ np.diag(pv) @ A[keep].T
    )
    got = marginal_loglik(padded_resid, A, padded_nv, m0, pv, mask=keep)
    assert float(got) == pytest.approx(float(dense), abs=1e-9)
    grad = jax.grad(lambda v: marginal_loglik(padded_resid, A, v, m0, pv, mask=keep))(padded_nv)
    assert bool(jnp.all(jnp.isfinite(grad))) and bool(jnp.all(grad[~keep] == 0))


def test_vmap_over_datasets() -> None:
    cases = [_case(s) for s in range(3)]
    stacked = [np.stack(x) for x in zip(*cases, strict=True)]
    got = jax.vmap(marginal_loglik)(*stacked)
    want = [marginal_loglik(*c) for c in cases]
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_conditional_beta_matches_dense_and_is_lower_cholesky() -> None:
    case = _case(2)
    mean, chol = conditional_beta(*case)
    dmean, dcov = _dense_posterior(*case)
    np.testing.assert_allclose(mean, dmean, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(chol @ chol.T, dcov, rtol=1e-10, atol=1e-13)
    assert np.all(np.triu(np.asarray(chol), 1) == 0) and np.all(np.diag(chol) > 0)


def test_draws_have_the_conditional_mean_and_covariance() -> None:
    case = _case(3)  # same shapes as above: no new compile of conditional_beta
    mean, chol = (np.asarray(a) for a in conditional_beta(*case))
    cov = chol @ chol.T
    n = 40_000
    draws = np.asarray(draw_beta(jax.random.key(0), *case, n=n))
    assert draws.shape == (n, 4)
    sd = np.sqrt(np.diag(cov))
    # mean: MC error sd/√n; covariance: relative MC error ≈ √(2/n) per entry
    assert np.all(np.abs(draws.mean(0) - mean) < 5 * sd / np.sqrt(n))
    emp = np.cov(draws, rowvar=False)
    assert np.all(np.abs(emp - cov) < 5 * np.sqrt(2.0 / n) * np.outer(sd, sd))
    one = draw_beta(jax.random.key(1), *case)
    assert one.shape == (4,)


def test_shape_errors_explain() -> None:
    resid, A, nv, m0, pv = _case()
    with pytest.raises(ValueError, match="same n"):
        marginal_loglik(resid[:-1], A, nv, m0, pv)
