"""The joint calibration model: marginalisation, MAP and posterior against simulated truth."""

import json

import dense_oracle as cm
import numpy as np
import pytest

from chekan import joint
from chekan.classical.fit import calibrate_record
from chekan.fit import fit_map_em, initial_values
from chekan.fit.map import between_passes
from chekan.fit.reported import map_derived
from chekan.joint.angles import AngleSensorSpec
from chekan.pipeline import CalibrationOptions, calibrate_file
from chekan.runtime.padding import padded_shape
from inference.linear import marginal_loglik
from inference.normal_eq import marginal_loglik_normal

TRUTH_VALUES = {
    "noise_scale": np.array([0.9, 1.1]),
    "sigma_theta_arcsec": 1.9,
    "sigma_hold_pix": 0.08,
}


def _setup(rec, encoder=False, angle_spec=None, padded=False):
    """``padded``: the model in its shape bucket, as ``calibrate --method map`` fits it (the
    padding carries no weight), its angle sensor's systematic terms bounded by 0″ where no
    ``angle_spec`` is given (they then carry no weight either: b₁ as without them, to
    3e-12 sd): the MAP tests share the paper's bucket, compiled by ``chekan warmup``,
    instead of compiling one of their own."""
    cres, _ = calibrate_record(rec, settle_s=200)
    if padded and angle_spec is None:
        angle_spec = AngleSensorSpec(0.0)
    holds, model = joint.prepare(rec, 200, encoder=encoder, angle_spec=angle_spec)
    if padded:
        model = model.pad(*padded_shape([model]))
    return cres, holds, model, joint.problem_for(model.structure)


@pytest.mark.parametrize("encoder,systematic", [(False, False), (True, False), (True, True)])
def test_normal_equations_equal_dense_marginal(short_session, encoder, systematic):
    _, rec, truth = short_session
    spec = AngleSensorSpec(3.0) if systematic else None
    _, _, model, prob = _setup(rec, encoder, spec)
    d = truth.derived()
    vals = {
        "b1": d["b1"],
        "b2": d["b2"],
        "K": truth.K_pix_per_rad,
        "eps1_arcmin": d["eps1_arcmin"],
        "eps2_arcmin": d["eps2_arcmin"],
        "dgamma_arcmin": d["dgamma_arcmin"],
        "tau_s": truth.tau_s,
        **TRUTH_VALUES,
    }
    v = prob.bayes_space.to_values(prob.bayes_space.to_z(vals))
    data = model.data
    f, A = cm.predict(v, model.structure, data)
    dense = marginal_loglik(
        (data.y - f).reshape(-1),
        A.reshape(-1, A.shape[-1]),
        cm.noise_var(v, data, cm.linear_terms(v, data)[3]).reshape(-1),
        0.0,
        cm.beta_prior_var(v, model.structure, data),
        mask=data.mask.reshape(-1),
    )
    ne, _ = cm.normal_equations(v, v, model.structure, data)
    fast = marginal_loglik_normal(ne, cm.beta_prior_var(v, model.structure, data))
    assert float(fast) == pytest.approx(float(dense), rel=1e-10)
    # β̂ from the normal equations solves the dense regularised least squares
    _, beta, _ = cm.solve_beta(v, v, model.structure, data)
    W = np.where(
        np.asarray(data.mask),
        1 / np.asarray(cm.noise_var(v, data, cm.linear_terms(v, data)[3])),
        0,
    ).reshape(-1)
    A2 = np.asarray(A).reshape(-1, A.shape[-1])
    r = np.where(np.asarray(data.mask), np.asarray(data.y - f), 0).reshape(-1)
    lhs = A2.T @ (W[:, None] * A2) + np.diag(
        1 / np.asarray(cm.beta_prior_var(v, model.structure, data))
    )
    np.testing.assert_allclose(lhs @ np.asarray(beta), A2.T @ (W * r), rtol=1e-8, atol=1e-8)


def test_map_recovers_truth(short_session):
    _, rec, truth = short_session
    cres, _, model, _ = _setup(rec, padded=True)
    fit = fit_map_em(model, initial_values(cres, rec.g_local_mgal))
    res, h, history = fit.result, fit.hyper, fit.history
    assert res.converged and all(p["converged"] for p in history)
    md = map_derived(fit)
    t = truth.derived()
    for k in ("b1", "b2", "a", "b1_0", "b2_0", "eps1_arcmin", "eps2_arcmin", "dgamma_arcmin"):
        mean, sd = md.values[k]
        assert abs(mean - t[k]) < 4 * sd, (k, mean, sd, t[k])
    assert abs(md.values["tau_s"][0] - truth.tau_s) < 4 * md.values["tau_s"][1]
    assert 1.0 < float(h["sigma_theta_arcsec"]) < 3.5  # true 2″
    assert 0.03 < float(h["sigma_hold_pix"]) < 0.15  # true 0.08 pix


def test_map_slow_damping_recentres_level_and_converges_em(short_program):
    """τ = 90 s: the level holds have not settled, so the classical m_h that the model
    starts from is pixels off. The MAP moves its level reference to the estimate (b is
    dG/dm about it) and runs the EM of the hyperparameters to its fixed point."""
    from chekan.records.simulate import Truth, simulate_session

    rec, truth = simulate_session(short_program, Truth(serial="T-slow", tau_s=90.0), seed=11)
    cres, _, model, _ = _setup(rec, padded=True)
    m_true = np.asarray(truth.m_level_pix)
    m_classical = np.asarray(model.data.m_ref).copy()
    assert np.all(np.abs(m_classical - m_true) > 3.0), m_classical - m_true
    fit = fit_map_em(model, initial_values(cres, rec.g_local_mgal))
    res, h = fit.result, fit.hyper
    np.testing.assert_allclose(np.asarray(fit.model.data.m_ref), m_true, atol=0.3)
    h2 = between_passes(fit.model, res.z, h)[1]
    for k in ("sigma_theta_arcsec", "sigma_hold_pix"):
        assert abs(np.log(float(h2[k]) / float(h[k]))) < 0.02, (k, h[k], h2[k])
    md = map_derived(fit)
    t = truth.derived()
    for k in ("b1", "b2", "a"):
        mean, sd = md.values[k]
        assert abs(mean - t[k]) < 3 * sd, (k, mean, sd, t[k])


def test_posterior_end_to_end(short_session, tmp_path):
    path, _, truth = short_session
    nc = tmp_path / "post.nc"
    res = calibrate_file(
        path,
        CalibrationOptions(
            method="bayes", settle_s=200, quick=True, netcdf=nc, progress=False, seed=2
        ),
    )
    d = res["diagnostics"]
    assert d["converged"], d["problems"]
    assert d["r_hat_max"] <= 1.01 and d["ess_bulk_min"] >= 400
    # the sampler's rule holds for every reported parameter, a and b₀ included (they carry
    # fresh draws of β | θ): bulk ESS ≥ its target
    from chekan.fit.sampling import sampler_config

    target = sampler_config(CalibrationOptions(quick=True)).target_ess
    assert min(p["ess_bulk"] for p in res["parameters"].values()) >= target
    t = truth.derived()
    for k in ("b1", "b2", "a", "eps1_arcmin", "eps2_arcmin"):
        p = res["parameters"][k]
        assert p["hdi_low"] <= t[k] <= p["hdi_high"], (k, p, t[k])
        assert {"mean", "sd", "hdi_low", "hdi_high", "unit", "r_hat", "ess_bulk"} <= set(p)
    ub = res["uncertainty_budget"]["b1"]
    # the posterior integrates the hyperparameters: k = 2, ν_eff not evaluated
    assert ub["coverage_factor"] == 2.0 and ub["nu_eff"] is None
    assert ub["expanded"] == pytest.approx(2 * res["parameters"]["b1"]["sd"])
    assert ub["angle_readout"] > 0 and ub["noise"] > 0
    assert len(res["drift_curve"]["t_h"]) == len(res["drift_curve"]["m1_pix"])
    pp = res["posterior_predictive_mgal"]
    assert set(pp["delta_g_low"]) == set(res["residuals_mgal"]["columns"])
    # the observed classical residuals mostly lie inside the predictive band
    inside = [
        lo <= x <= hi
        for c in pp["columns"]
        for x, lo, hi in zip(
            res["residuals_mgal"]["delta_g_mgal"][c],
            pp["delta_g_low"][c],
            pp["delta_g_high"][c],
            strict=True,
        )
    ]
    assert np.mean(inside) > 0.7
    import arviz as az

    idata = az.from_netcdf(res["posterior_netcdf"])
    for group in (
        "posterior",
        "sample_stats",
        "observed_data",
        "posterior_predictive",
        "log_likelihood",
    ):
        assert group in idata.groups()
    assert idata.posterior["b1"].shape[0] == 4  # four independent ensembles = chains
    json.dumps(res)  # serialisable as is
    from test_result_keys import private_keys

    assert list(private_keys(res)) == []  # no private key in a bayes result either


def test_protocol_posterior_centred_on_printed_b(paper_protocol):
    res = calibrate_file(paper_protocol, CalibrationOptions(method="bayes", progress=False))
    assert res["diagnostics"]["converged"]
    for r in res["rounds"]:
        for j in (1, 2):
            m = r[f"model_b{j}"]
            assert abs(m["mean"] - r["b_printed"][j - 1]) < m["sd"]
    assert 1.0 < res["parameters"]["sigma_theta_arcsec"]["mean"] < 4.0
    m = calibrate_file(paper_protocol, CalibrationOptions(method="map", progress=False))
    assert m["diagnostics"]["converged"]
    assert m["parameters"]["b1"]["mean"] == pytest.approx(res["parameters"]["b1"]["mean"], abs=2e-3)


def test_unidentifiable_azimuth_is_reported_not_fatal(tmp_path):
    """Small tilts about one axis hardly inform Δγ: the result says it is prior-dominated."""
    from chekan.physics.program import build_program
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session

    prog = build_program([0.3, 0.6], dwell_s=300, settle_s=200, rounds=1)
    rec, _ = simulate_session(prog, Truth(m_level_pix=(1024.0, 1024.0)), seed=5)
    path = tmp_path / "r.csv"
    write_record(path, rec)
    res = calibrate_file(path, CalibrationOptions(method="map", progress=False))
    assert "dgamma_arcmin" in res["diagnostics"]["prior_dominated"]
    assert np.isfinite(res["parameters"]["b1"]["mean"])
