"""inference.box_newton: projected Newton in a box, against analytic minima and SciPy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import minimize

from inference.box_newton import minimise_in_box


def test_a_quadratic_with_one_bound_active_has_its_analytic_minimum():
    # f = ½(x−c)ᵀA(x−c); with x₀ ≤ 0 active, the others solve A_FF x_F = A_FF c_F − A_F0·0
    A = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.3], [0.0, 0.3, 3.0]])
    c = np.array([1.0, -2.0, 0.5])

    def f(x):
        d = x - c
        return 0.5 * d @ jnp.asarray(A) @ d

    lo, hi = jnp.array([-5.0, -5.0, -5.0]), jnp.array([0.0, 5.0, 5.0])
    res = jax.jit(lambda x0: minimise_in_box(f, x0, lo, hi))(jnp.zeros(3))
    free = [1, 2]
    x = np.zeros(3)
    x[free] = np.linalg.solve(
        A[np.ix_(free, free)], A[np.ix_(free, free)] @ c[free] - A[free, 0] * (0 - c[0])
    )
    np.testing.assert_allclose(np.asarray(res.x), x, atol=1e-12)
    # the multiplier of the active bound has the right sign: ∂f/∂x₀ < 0 there (wants up)
    assert float(jax.grad(f)(res.x)[0]) < 0


@pytest.mark.parametrize("x0", [[0.0, 0.0, -5.8], [3.0, -2.0, -1.0]])
def test_a_noise_likelihood_matches_scipy_lbfgsb_converged_tightly(x0):
    # the shape of the EM's noise M-step: v = e^{2a}b + e^{2k}t², Σ log v + e/v, in a box
    rng = np.random.default_rng(3)
    b, t2 = rng.uniform(0.5, 2.0, 200), rng.uniform(0.0, 3.0, 200) ** 2
    e = (1.3**2 * b + 0.02**2 * t2) * rng.chisquare(1, 200)

    def f(x):
        v = jnp.exp(2 * x[0]) * b + jnp.exp(2 * x[2]) * t2 + jnp.exp(2 * x[1])
        return 0.5 * jnp.sum(jnp.log(v) + e / v) + 0.5 * x[0] ** 2

    lo, hi = np.log([0.05, 1e-3, 1e-5]), np.log([50.0, 0.5, 0.5])
    res = jax.jit(lambda z: minimise_in_box(f, z, jnp.asarray(lo), jnp.asarray(hi)))(
        jnp.asarray(x0)
    )
    ref = minimize(
        lambda x: float(f(jnp.asarray(x))),
        np.clip(x0, lo, hi),
        jac=lambda x: np.asarray(jax.grad(f)(jnp.asarray(x))),
        method="L-BFGS-B",
        bounds=list(zip(lo, hi, strict=True)),
        options={"ftol": 1e-15, "gtol": 1e-11, "maxiter": 10_000},
    )
    assert float(res.f) <= ref.fun + 1e-9
    np.testing.assert_allclose(np.asarray(res.x), ref.x, atol=2e-5)
    assert int(res.num_steps) < 50
