"""MAP + Laplace against analytic posteriors; batching; degenerate models."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from chekan.runtime.compiler import Compiler
from inference import (
    LeastSquaresProblem,
    Param,
    ParamSpace,
    fit_map,
    fit_map_batch,
    laplace_covariance,
)
from inference.map import trace_count

SIGMA = 0.3
PRIOR_SD = 2.0


def _linreg(seed: int = 0, n: int = 40, p: int = 3):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, p))
    beta = np.array([1.0, -2.0, 0.5])[:p]
    y = X @ beta + SIGMA * rng.normal(size=n)
    space = ParamSpace([Param("beta", loc=0.0, scale=PRIOR_SD, shape=(p,))])
    problem = LeastSquaresProblem(
        space, lambda v, d: (d["y"] - d["X"] @ v["beta"]) / SIGMA, Compiler()
    )
    precision = X.T @ X / SIGMA**2 + np.eye(p) / PRIOR_SD**2
    cov = np.linalg.inv(precision)
    mean = cov @ (X.T @ y) / SIGMA**2
    return problem, {"X": X, "y": y}, mean, cov


def test_linear_regression_matches_analytic_posterior() -> None:
    problem, data, mean, cov = _linreg()
    res = fit_map(problem, data)
    assert res.converged, res.message
    np.testing.assert_allclose(res.values["beta"], mean, rtol=0, atol=1e-8)
    np.testing.assert_allclose(res.cov_values("beta"), cov, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(res.sd()["beta"], np.sqrt(np.diag(cov)), rtol=1e-8)
    assert res.degenerate == [] and np.isfinite(res.jacobian_cond)
    # cost = ½‖stacked residuals‖² at the analytic mean
    r = np.asarray(problem.stacked_residuals(problem.space.to_z({"beta": mean}), data))
    assert res.cost == pytest.approx(0.5 * r @ r, rel=1e-10)
    assert "beta[2]" in res.summary()


def test_gauss_newton_and_values_as_start() -> None:
    problem, data, mean, _ = _linreg()
    res = fit_map(problem, data, {"beta": np.ones(3)}, solver="gn")
    assert res.converged
    np.testing.assert_allclose(res.values["beta"], mean, atol=1e-8)
    with pytest.raises(ValueError, match="solver"):
        fit_map(problem, data, solver="bfgs")


# --------------------------------------------------------------------------- nonlinear
T = np.linspace(0.0, 6.0, 60)
NOISE = 0.05
TRUTH = {"A": 3.0, "tau": 1.5}


def _decay_problem() -> LeastSquaresProblem:
    """y = A exp(-t/τ) with τ log-transformed (prior: log τ ~ N(log 2, 1))."""
    space = ParamSpace(
        [
            Param("A", loc=0.0, scale=10.0, unit="V"),
            Param("tau", loc=float(np.log(2.0)), scale=1.0, transform="log", unit="s"),
        ]
    )

    def residuals(v, d):
        return (d["y"] - v["A"] * jnp.exp(-d["t"] / v["tau"])) / NOISE

    return LeastSquaresProblem(space, residuals, Compiler())


def _decay_data(seed: int, truth=TRUTH) -> dict:
    rng = np.random.default_rng(seed)
    y = truth["A"] * np.exp(-T / truth["tau"]) + NOISE * rng.normal(size=T.size)
    return {"t": T, "y": y}


DECAY = _decay_problem()  # one object for the module: compiled solvers are cached per problem


def test_exponential_decay_recovers_truth() -> None:
    problem = DECAY
    res = fit_map(problem, _decay_data(1))
    assert res.converged, res.message
    sd = res.sd()
    for k, v in TRUTH.items():
        assert abs(float(res.values[k]) - v) < 3 * float(sd[k]), (k, res.values[k], sd[k])
    # delta method for the log transform: sd(τ) = τ · sd(log τ)
    cov_u = res.cov_u()
    assert float(sd["tau"]) == pytest.approx(float(res.values["tau"]) * np.sqrt(cov_u[1, 1]))


def test_batch_equals_individual_fits_and_does_not_retrace() -> None:
    problem = DECAY
    rng = np.random.default_rng(7)
    truths = [{"A": rng.uniform(1, 5), "tau": rng.uniform(0.5, 3)} for _ in range(8)]
    datasets = [_decay_data(100 + i, tr) for i, tr in enumerate(truths)]
    batch_data = {"t": T, "y": np.stack([d["y"] for d in datasets])}
    axes = {"t": None, "y": 0}

    batch = fit_map_batch(problem, batch_data, data_axes=axes)
    n_traces = trace_count(problem)
    # same shapes, one broken lane (NaN data): no retrace, the other lanes are unaffected
    y_bad = batch_data["y"].copy()
    y_bad[3, 10] = np.nan
    batch2 = fit_map_batch(problem, {"t": T, "y": y_bad}, data_axes=axes)
    assert trace_count(problem) == n_traces, "same shapes must not retrace"
    ok = np.arange(8) != 3
    assert not batch2.converged[3] and batch2.messages[3] != "success"
    assert batch2.converged[ok].all() and np.isnan(batch2.sd["A"][3])
    np.testing.assert_allclose(batch2.z[ok], batch.z[ok], atol=1e-8)

    # in vmapped groups of 3 lanes (the last group padded): the same answers, lane by lane
    grouped = fit_map_batch(problem, batch_data, data_axes=axes, max_lanes=3)
    np.testing.assert_allclose(grouped.z, batch.z, atol=1e-10)
    np.testing.assert_array_equal(grouped.converged, batch.converged)
    assert len(grouped.messages) == 8

    assert batch.converged.all(), batch.messages
    for i, d in enumerate(datasets):
        single = fit_map(problem, d)
        item = batch.item(i)
        np.testing.assert_allclose(item.z, single.z, atol=1e-8)
        for k in ("A", "tau"):
            np.testing.assert_allclose(item.values[k], single.values[k], atol=1e-8)
            np.testing.assert_allclose(batch.sd[k][i], single.sd()[k], rtol=1e-6)
        assert item.cost == pytest.approx(single.cost, rel=1e-9)
    n_traces = trace_count(problem)
    fit_map(problem, datasets[0])
    assert trace_count(problem) == n_traces, "repeated fit_map must not retrace"


# --------------------------------------------------------------------------- degenerate
def test_degenerate_model_is_flagged_not_crashed() -> None:
    t = np.linspace(0, 1, 30)
    rng = np.random.default_rng(3)
    y = 2.0 * t + 0.5 + 0.1 * rng.normal(size=t.size)
    space = ParamSpace([Param("p1"), Param("p2"), Param("c", scale=5.0)])
    problem = LeastSquaresProblem(
        space, lambda v, d: (d["y"] - (v["p1"] + v["p2"]) * d["t"] - v["c"]) / 0.1, Compiler()
    )
    res = fit_map(problem, {"t": t, "y": y})
    assert res.degenerate == ["p1", "p2"]
    assert res.jacobian_cond > 1e8
    sd = res.sd()
    assert np.isinf(sd["p1"]) and np.isinf(sd["p2"])
    assert np.isfinite(sd["c"]) and 0 < sd["c"] < 1  # identified coordinate keeps its sd
    # the identified combination p1 + p2 is still estimated
    assert float(res.values["p1"] + res.values["p2"]) == pytest.approx(2.0, abs=0.3)
    np.testing.assert_allclose(
        np.abs(res.degenerate_directions), [[0.5**0.5, 0.5**0.5, 0]], atol=1e-8
    )


def test_laplace_covariance_function() -> None:
    rng = np.random.default_rng(0)
    J = rng.normal(size=(20, 4))
    cov, cond, dirs = laplace_covariance(J)
    np.testing.assert_allclose(cov, np.linalg.inv(J.T @ J), rtol=1e-10)
    assert cond == pytest.approx(np.linalg.cond(J)) and dirs.shape == (0, 4)
    J[:, 3] = J[:, 0]  # exactly collinear columns
    cov, cond, dirs = laplace_covariance(J)
    assert dirs.shape == (1, 4) and np.isinf(cov[0, 0]) and np.isinf(cov[3, 3])
    assert cov[0, 3] == -np.inf and np.isfinite(cov[1, 1])


def test_a_failed_lane_keeps_its_code_and_says_it_in_words() -> None:
    """``result_code`` is optimistix's code (0: success); ``message`` puts it in words only
    when read (the text needs optimistix imported, which a process running stored
    executables otherwise never does)."""
    import optimistix as optx

    y = _decay_data(3)["y"].copy()
    batch = fit_map_batch(
        DECAY,
        {"t": T, "y": np.stack([y, np.where(np.arange(T.size) == 5, np.nan, y)])},
        data_axes={"t": None, "y": 0},
    )
    assert batch.result_codes.tolist()[0] == 0 and batch.result_codes[1] != 0
    failed = batch.item(1)
    assert failed.result_code == int(batch.result_codes[1]) and not failed.converged
    table = optx.RESULTS._index_to_message  # type: ignore[attr-defined]
    assert failed.message == table[failed.result_code] != "success"
    assert batch.item(0).message == "success" and batch.messages == ["success", failed.message]


@pytest.mark.parametrize("stored", [False, True])
def test_a_solved_problem_and_its_store_are_freed_with_their_last_reference(tmp_path, stored):
    """JAX keeps the argument trees of what it traced in a process-wide cache
    (``jax._src.api_util.donation_vector``, which ``jax.clear_caches()`` leaves alone). A solve
    whose residual function was the problem's bound method left the problem there, and with
    it its executable store and every executable loaded in it, after the last reference
    went (a worker that met many structures kept them all)."""
    import gc
    import weakref

    from chekan.runtime.store import ExecutableStore

    base, data, mean, _ = _linreg(seed=4)
    store = ExecutableStore(tmp_path, "freed-test") if stored else Compiler()
    problem = LeastSquaresProblem(base.space, base.residuals, executables=store)
    res = fit_map(problem, data, solver="gn")
    np.testing.assert_allclose(res.values["beta"], mean, atol=1e-8)
    alive = [weakref.ref(problem)] + ([weakref.ref(store)] if store is not None else [])
    del problem, store, res
    gc.collect()
    assert [r() for r in alive] == [None] * len(alive)
