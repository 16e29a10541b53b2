"""Gauss–Newton's decrement test (inference.gauss_newton, ``fit_map(..., sd_tol=)``):
it stops earlier than the Cauchy test and lands within ``sd_tol`` posterior sds of the
optimum, with residuals that are those of the point it returns."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from chekan.runtime.compiler import Compiler
from inference import LeastSquaresProblem, Param, ParamSpace, fit_map, fit_map_batch

T = np.linspace(0.0, 6.0, 80)
NOISE = 0.05


def _problem() -> LeastSquaresProblem:
    """y = A exp(−t/τ), τ log-transformed; fitted to data with an offset the model lacks,
    so the residuals at the optimum are large and Gauss–Newton converges linearly."""
    space = ParamSpace(
        [
            Param("A", loc=0.0, scale=10.0),
            Param("tau", loc=float(np.log(2.0)), scale=1.0, transform="log"),
        ]
    )

    def residuals(v, d):
        return (d["y"] - v["A"] * jnp.exp(-d["t"] / v["tau"])) / NOISE

    return LeastSquaresProblem(space, residuals, Compiler())


def _data(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    y = 3.0 * np.exp(-T / 1.5) + 0.2 + NOISE * rng.normal(size=T.size)
    return {"t": T, "y": y}


def _mahalanobis(dz: np.ndarray, cov_z: np.ndarray) -> float:
    return float(np.sqrt(dz @ np.linalg.solve(cov_z, dz)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_stops_earlier_within_sd_tol_of_the_optimum(seed: int) -> None:
    problem, data = _problem(), _data(seed)
    z0 = problem.space.to_z({"A": 1.0, "tau": 4.0})
    tight = fit_map(problem, data, z0, solver="gn", rtol=1e-13, atol=1e-13, max_steps=200)
    cauchy = fit_map(problem, data, z0, solver="gn", rtol=1e-8, atol=1e-8, max_steps=200)
    fast = fit_map(problem, data, z0, solver="gn", rtol=1e-8, atol=1e-8, max_steps=200, sd_tol=1e-4)
    assert tight.converged and cauchy.converged and fast.converged
    assert fast.num_steps < cauchy.num_steps
    assert _mahalanobis(fast.z - tight.z, tight.cov_z) < 1e-4
    # the returned residuals are those of the returned point (r + Jδ, first order in δ)
    r_true = np.asarray(problem.stacked_residuals(jnp.asarray(fast.z), data))
    np.testing.assert_allclose(fast.residuals, r_true, rtol=0, atol=1e-9 * np.abs(r_true).max())
    assert fast.cost == pytest.approx(tight.cost, rel=1e-12)
    np.testing.assert_allclose(fast.cov_z, tight.cov_z, rtol=1e-5)


def test_a_start_at_the_optimum_stops_after_one_linearisation() -> None:
    problem, data = _problem(), _data(0)
    tight = fit_map(problem, data, solver="gn", rtol=1e-13, atol=1e-13, max_steps=200)
    again = fit_map(problem, data, tight.z, solver="gn", sd_tol=1e-4)
    assert again.converged and again.num_steps == 1
    np.testing.assert_allclose(again.z, tight.z, rtol=0, atol=1e-10)


def test_batch_lanes_equal_single_solves() -> None:
    problem = _problem()
    datas = [_data(s) for s in (3, 4)]
    stacked = {"t": np.stack([T, T]), "y": np.stack([d["y"] for d in datas])}
    batch = fit_map_batch(problem, stacked, solver="gn", sd_tol=1e-4)
    for i, d in enumerate(datas):
        one = fit_map(problem, d, solver="gn", sd_tol=1e-4)
        np.testing.assert_allclose(batch.z[i], one.z, rtol=0, atol=1e-10)
        assert batch.num_steps[i] >= one.num_steps  # lanes run in lock step


def test_bad_settings_are_refused() -> None:
    problem, data = _problem(), _data(0)
    with pytest.raises(ValueError, match="solver='gn'"):
        fit_map(problem, data, solver="lm", sd_tol=1e-4)
    for bad in (0.0, 1.0, -1e-3):
        with pytest.raises(ValueError, match="fraction of a standard deviation"):
            fit_map(problem, data, solver="gn", sd_tol=bad)


def test_the_solver_takes_pytrees_as_optimistix_solvers_do() -> None:
    """Used directly with ``optimistix.least_squares``: parameters and residuals as dicts
    (the decrement is the 2-norm over every leaf). A linear problem: one step is exact,
    and the second linearisation sees a zero step."""
    import optimistix as optx

    from inference import DecrementGaussNewton

    A = np.array([[2.0, 0.5], [0.0, 1.0], [1.0, 1.0]])
    y = np.array([1.0, -2.0, 0.5])

    def fn(p, _):
        x = jnp.stack([p["a"], p["b"]])
        r = A @ x - y
        return {"first": r[:2], "last": r[2]}

    sol = optx.least_squares(
        fn, DecrementGaussNewton(1e-12, 1e-12, 1e-6), {"a": 0.0, "b": 0.0}, max_steps=10
    )
    x_ls = np.linalg.lstsq(A, y, rcond=None)[0]
    np.testing.assert_allclose([sol.value["a"], sol.value["b"]], x_ls, atol=1e-12)
    assert int(sol.stats["num_steps"]) == 2
