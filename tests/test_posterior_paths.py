"""``bayes``'s two samplers on records: importance sampling from the fitted proposal (the
fast path, where it is reliable) and emcee (the reference) agree, and a point is weighed and
its β drawn in one evaluation whose log-density is the model's."""

from __future__ import annotations

import numpy as np
import pytest

from bench.several_records import paths_tolerance  # the agreement, as the bench's
from chekan.pipeline import CalibrationOptions, calibrate_file


def _agree(fast: dict, ref: dict) -> None:
    for name, e in ref["parameters"].items():
        f = fast["parameters"][name]
        tol_mean, tol_sd = paths_tolerance(name)
        assert abs(f["mean"] - e["mean"]) <= tol_mean * e["sd"], (name, f, e)
        assert abs(f["sd"] / e["sd"] - 1) <= tol_sd, (name, f["sd"], e["sd"])


def _both(path, **kw) -> tuple[dict, dict]:
    opts = dict(method="bayes", progress=False, seed=4, **kw)
    fast = calibrate_file(path, CalibrationOptions(sampler="auto", **opts))
    ref = calibrate_file(path, CalibrationOptions(sampler="emcee", **opts))
    return fast, ref


def test_importance_sampling_agrees_with_emcee_on_a_short_session(short_session) -> None:
    fast, ref = _both(short_session[0], settle_s=200, quick=True)
    d = fast["diagnostics"]
    assert d["sampler"] == "importance" and d["importance"]["taken"], d.get("importance")
    assert d["importance"]["pareto_k"] < 0.7 and d["importance"]["ess_min"] >= 1000
    assert d["converged"] and d["ess_bulk_min"] >= 1000  # every reported quantity
    assert "n_steps" not in d and "tau_max" not in d  # emcee's figures only where it ran
    assert ref["diagnostics"]["sampler"] == "emcee" and ref["diagnostics"]["n_steps"] > 0
    _agree(fast, ref)


@pytest.mark.slow
def test_importance_sampling_agrees_with_emcee_on_the_papers_program(tmp_path) -> None:
    from chekan.demo import demo_program
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session

    rec, _ = simulate_session(demo_program(quick=False), Truth(serial="T-9h"), seed=21)
    path = tmp_path / "paper.csv"
    write_record(path, rec)
    fast, ref = _both(path)
    assert fast["diagnostics"]["sampler"] == "importance", fast["diagnostics"]["importance"]
    _agree(fast, ref)


def test_one_evaluation_weighs_a_point_and_draws_its_beta(short_session) -> None:
    """The log-density that comes with a point's draws equals the model's marginal
    log-density (:meth:`CalibrationProblem.log_density`) to round-off."""
    import jax

    from chekan.classical.fit import calibrate_record
    from chekan.fit import fit_map_em, initial_values
    from chekan.fit.sampling import weighed_draws
    from chekan.joint import prepare
    from chekan.joint.angles import AngleSensorSpec
    from chekan.runtime.engine import problem_for
    from chekan.runtime.padding import padded_shape

    _, rec, _ = short_session
    cres, _ = calibrate_record(rec, settle_s=200)
    # in the paper's bucket, as chekan warmup compiles it (a 0″ bound: no systematic weight)
    _, model = prepare(rec, 200, angle_spec=AngleSensorSpec(0.0))
    model = model.pad(*padded_shape([model]))
    fit = fit_map_em(model, initial_values(cres, rec.g_local_mgal))
    prob = problem_for(model.structure)
    space = prob.bayes_space
    values = {p.name: fit.result.values[p.name] for p in prob.theta_space.params}
    values.update({k: np.asarray(v) for k, v in fit.hyper.items()})
    z0 = np.asarray(space.to_z(values))
    points = z0 + 0.05 * np.random.default_rng(3).standard_normal((6, z0.size))
    lp, draws = weighed_draws(fit, 0, points, 0)
    data = fit.model.data  # the level reference at the MAP's estimate, as the sampler's
    ref = np.array([float(jax.jit(prob.log_density)(z, data)) for z in points])
    np.testing.assert_allclose(lp, ref, rtol=1e-10)
    assert draws["b1"].shape == (1, 6)
    assert draws.log_density is not None and np.array_equal(draws.log_density[0], lp)
