"""SQUAREM (inference.squarem) against analytic fixed points: a slow linear contraction, a
fixed point on a bound that plain iteration only creeps towards, and its bookkeeping."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from inference.squarem import squarem

LOWER = jnp.full(3, -1e3)
UPPER = jnp.full(3, 1e3)


def _contraction(rate: float):
    """F(x) = A x + b with A symmetric, its eigenvalues 0.2, 0.6 and ``rate``."""
    q, _ = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))
    a = q @ np.diag([0.2, 0.6, rate]) @ q.T
    b = np.array([0.3, -0.2, 0.1])
    return (lambda x: jnp.asarray(a) @ x + jnp.asarray(b)), np.linalg.solve(np.eye(3) - a, b)


def test_a_slow_contraction_reaches_its_fixed_point_in_a_few_updates():
    f, want = _contraction(0.995)  # plain iteration: ~1 800 updates to move less than 1e-8
    sol = jax.jit(lambda x: squarem(f, x, LOWER, UPPER, tol=1e-10, max_updates=300))(jnp.zeros(3))
    np.testing.assert_allclose(sol.x, want, atol=1e-7)
    assert float(sol.change) < 1e-10
    assert int(sol.num_updates) <= 60 and int(sol.num_updates) % 3 == 0


def test_a_fixed_point_on_the_bound_is_reached_not_crept_towards():
    """x ← max(0.98·x, l): plain iteration from 1 needs 148 updates to reach l = 0.05; the
    extrapolation overshoots, the projection puts it on l, where F(l) = l."""
    lo, hi = jnp.asarray([0.05]), jnp.asarray([5.0])

    def f(x):
        return jnp.clip(0.98 * x, lo, hi)

    sol = squarem(f, jnp.asarray([1.0]), lo, hi, tol=1e-4, max_updates=200)
    assert float(sol.x[0]) == 0.05
    assert int(sol.num_updates) <= 12


def test_a_converged_start_is_returned_as_it_is_and_the_cap_holds():
    f, _ = _contraction(0.995)
    x0 = jnp.asarray([1.0, 2.0, 3.0])
    done = squarem(f, x0, LOWER, UPPER, tol=1e-4, max_updates=200, num_updates=7, change=0.0)
    np.testing.assert_array_equal(done.x, x0)
    assert int(done.num_updates) == 7 and float(done.change) == 0.0
    capped = squarem(f, jnp.zeros(3), LOWER, UPPER, tol=1e-30, max_updates=10, num_updates=2)
    assert int(capped.num_updates) == 8  # 2 + two steps of three; a third would pass 10
    assert float(capped.change) >= 1e-30


def test_a_non_finite_extrapolation_falls_back_to_two_plain_updates():
    """A translation F(x) = x + 1 in an unbounded box: v = 0, so the step length overflows
    and the extrapolated point is not a number; the step is then F(F(F(x))) = x + 3."""
    lo, hi = jnp.full(1, -jnp.inf), jnp.full(1, jnp.inf)
    sol = squarem(lambda x: x + 1.0, jnp.zeros(1), lo, hi, tol=0.0, max_updates=3)
    np.testing.assert_array_equal(sol.x, [3.0])
    assert int(sol.num_updates) == 3
