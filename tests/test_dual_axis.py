"""Rounds about both platform axes (issue 30): the simulator tilts about X and Y with each
angle sensor's own errors, holds know their axis, and the joint model calibrates such a
record with one systematic line per angle sensor and the X response's nuisance."""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from chekan.errors import ChekanError
from chekan.options import CalibrationOptions
from chekan.physics.program import build_program
from chekan.pipeline import calibrate
from chekan.records.holds import segment_record
from chekan.records.simulate import Truth, random_truth, session_systematic, simulate_session


def _program(rounds: int = 4):
    return build_program(
        [4.5, 4 + 51 / 60, 5 + 10 / 60], axis="xy", rounds=rounds, dwell_s=300, settle_s=120
    )


def test_simulated_record_tilts_about_both_axes_with_each_sensors_own_error():
    prog = _program()
    truth = Truth(angle_systematic_arcsec=3.0, angle_error_sd_arcsec=0.0, tilt_jitter_arcsec=0.0)
    rec, truth = simulate_session(prog, truth, seed=3)
    holds = segment_record(rec, settle_s=prog.settle_s)
    tilts = ~holds.is_level
    # every tilt hold about its commanded axis, the other axis near zero
    want = np.array([s.axis for s in prog.steps])[holds.step]
    assert list(holds.hold_axis[tilts]) == list(want[tilts])
    assert holds.axis == "xy"
    assert [r.axis for r in holds.rounds] == ["y", "x", "y", "x"]
    about_x = tilts & (holds.hold_axis == "x")
    cmd_x = np.array([s.tilt_x_rad for s in prog.steps])[holds.step]
    np.testing.assert_allclose(holds.tilt_x_rad[about_x], cmd_x[about_x], atol=1e-9)
    # the two sensors' systematic errors are drawn apart, and each step carries its own
    fy = session_systematic(truth, prog, 3, "y")
    fx = session_systematic(truth, prog, 3, "x")
    grid = np.deg2rad(np.linspace(-5, 5, 11))
    assert not np.allclose(fy(grid), fx(grid))
    sys_step = np.asarray(truth.angle_systematic_per_step_arcsec)
    theta = np.array([s.theta_rad for s in prog.steps])
    on_x = np.array([s.axis == "x" for s in prog.steps])
    np.testing.assert_allclose(sys_step[on_x], fx(theta[on_x]))
    np.testing.assert_allclose(sys_step[~on_x], fy(theta[~on_x]))
    # the true attitude is the commanded one minus the sensor's error, about the hold's axis
    k = int(np.flatnonzero(on_x & (np.abs(theta) > 0))[0])
    err = truth.angle_error_arcsec[k]
    assert err == pytest.approx(sys_step[k])
    assert abs(err) > 0.1


def test_single_axis_simulation_is_unchanged_by_the_second_sensor():
    """A program about Y draws exactly what it drew before the X sensor existed."""
    prog = build_program([2.0, 4.0], rounds=1, dwell_s=120, settle_s=60)
    a, _ = simulate_session(prog, Truth(), seed=5)
    b, _ = simulate_session(prog, dataclasses.replace(Truth(), angle_systematic_x_arcsec=0.5), 5)
    np.testing.assert_array_equal(a.m1_pix, b.m1_pix)
    np.testing.assert_array_equal(a.tilt_x_arcsec, b.tilt_x_arcsec)


@pytest.fixture(scope="module")
def dual_fit():
    prog = _program()
    truth = random_truth(
        np.random.default_rng(11),
        angle_systematic_arcsec=3.0,
        angle_error_sd_arcsec=0.8,
        x_unmodelled_odd_pix=(1.5, -1.0),
        x_unmodelled_even_pix=(0.02, -0.02),
    )
    rec, truth = simulate_session(prog, truth, seed=11)
    res = calibrate(rec, CalibrationOptions(method="map", progress=False))
    return rec, truth, res


@pytest.mark.slow
def test_map_of_a_two_axis_record_covers_the_truth(dual_fit):
    _rec, truth, res = dual_fit
    t = truth.derived()
    for name in ("b1", "b2", "a"):
        p = res["parameters"][name]
        assert abs(p["mean"] - t[name]) < 3 * p["sd"], (name, p, t[name])
    assert res["diagnostics"]["converged"]


@pytest.mark.slow
def test_budget_has_a_line_per_angle_sensor_and_the_x_response(dual_fit):
    _rec, _truth, res = dual_fit
    for name in ("b1", "b2"):
        line = res["uncertainty_budget"][name]
        assert line["angle_systematic_y"] > 0 and line["angle_systematic_x"] > 0
        assert "angle_systematic" not in line
        # the scale error both sensors may share, u = 3″/√3/√2 at θ_max = 5°10′: the data
        # cannot reveal it (it scales every tilt's Δg as b does), so b carries its prior
        # one to one, δb/b = 2ξ/θ_max
        u_common = 3.0 / np.sqrt(3.0) / np.sqrt(2.0)
        want = 2 * u_common / ((5 + 10 / 60) * 3600) * res["parameters"][name]["mean"]
        assert line["angle_systematic_xy"] == pytest.approx(want, rel=0.05)
        assert "x_response" in line
        footer = ("total", "nu_eff", "coverage_factor", "expanded")
        parts = [v for k, v in line.items() if k not in footer]
        assert np.sqrt(np.sum(np.square(parts))) == pytest.approx(line["total"], rel=1e-6)
    sensors = res["angle_sensors"]
    assert sensors["y"]["axis"] == "y" and sensors["x"]["axis"] == "x"
    assert sensors["x"]["bound_arcsec"] == 3.0


@pytest.mark.slow
def test_a_tighter_x_bound_shrinks_the_x_sensors_line_and_leaves_b_on_the_y_rounds(dual_fit):
    rec, _truth, res = dual_fit
    meta = {**rec.meta, "platform_angle_bound_x_arcsec": "0.5"}
    tight = calibrate(
        dataclasses.replace(rec, meta=meta), CalibrationOptions(method="map", progress=False)
    )
    before, after = res["uncertainty_budget"]["b1"], tight["uncertainty_budget"]["b1"]
    x_ratio = after["angle_systematic_x"] / before["angle_systematic_x"]
    y_ratio = after["angle_systematic_y"] / before["angle_systematic_y"]
    # the X rounds' even response measures b only together with the pendulums' horizontal
    # (its sin²θ column, chekan.joint.xresponse.level_angle_column, is b's own shape), so b
    # rests on the Y rounds and the X rounds reach it through a (K): with the X sensor known
    # 6× better its line shrinks about as much, and the Y line stays (before the horizontal
    # was carried, b leaned on the X rounds: x_ratio < 0.7, y_ratio < 0.9)
    assert x_ratio < 0.3 and 0.95 < y_ratio < 1.05, (x_ratio, y_ratio)
    assert after["total"] < before["total"]
    assert tight["angle_sensors"]["x"]["bound_arcsec"] == 0.5


@pytest.mark.slow
def test_a_known_horizontal_is_an_input_and_pins_a(dual_fit, tmp_path):
    """The pendulums' horizontal about the CCD centre is a stated Type B input: by default
    the model's own 100 pix (its source says so), or the instrument's figure given as
    ``horizontal_u_pix``. Known to 0.5 pix, the X rounds' even response tells a's share from
    the horizontal's sin²θ (the designer: a's sd on such a program about halves; on this
    4-round record it shrinks by at least 20 %), and b is not worse."""
    from chekan.joint.xresponse import M0_SOURCE

    rec, truth, res = dual_fit
    assert res["pendulum_horizontal"] == {
        "about": "ccd_center_pix",
        "u_pix": 100.0,
        "source": M0_SOURCE,
    }
    known = calibrate(rec, CalibrationOptions(method="map", progress=False, horizontal_u_pix=0.5))
    assert known["pendulum_horizontal"]["u_pix"] == 0.5
    assert known["pendulum_horizontal"]["source"] == "--horizontal-u-pix"
    p0, p1 = res["parameters"], known["parameters"]
    assert p1["a"]["sd"] < 0.8 * p0["a"]["sd"], (p0["a"]["sd"], p1["a"]["sd"])
    assert p1["b1"]["sd"] <= 1.001 * p0["b1"]["sd"]
    t = truth.derived()
    for name in ("b1", "b2", "a"):  # the simulated horizontal is the centre: still covered
        assert abs(p1[name]["mean"] - t[name]) < 3 * p1[name]["sd"], name
    with pytest.raises(ChekanError, match="horizontal"):
        CalibrationOptions(method="map", horizontal_u_pix=0.0)
    # the certificate states it: the budget's label, and the DCC's influence conditions
    from chekan.report.tables import horizontal_u_text

    assert horizontal_u_text(res) == "100" and horizontal_u_text(known, "ru") == "0,5"
    pytest.importorskip("xmlschema")
    from chekan.report.dcc import DCC_NS, build_dcc, dcc_bytes, load_lab, validate_dcc

    lab = tmp_path / "lab.toml"
    lab.write_text(
        '[lab]\nname = "L"\ncode = "L1"\nemail = "l@example.org"\nstreet = "S 1"\n'
        'city = "C"\npost_code = "1"\ncountry_code = "RU"\naccreditation = "A"\n'
        '[responsible]\nname = "N"\n',
        encoding="utf-8",
    )
    xml = dcc_bytes(build_dcc(known, load_lab(lab)))
    validate_dcc(xml)
    conditions = {
        ic.get("refType"): "".join(ic.itertext())
        for ic in ET.fromstring(xml).iter(f"{{{DCC_NS}}}influenceCondition")
    }
    assert "0.5" in conditions["chekan_pendulumHorizontal"]
    root = ET.fromstring(xml)
    u = root.find(f".//{{{DCC_NS}}}quantity[@refType='chekan_horizontal_u_pix']")
    assert float(u.findtext(".//{https://ptb.de/si}value")) == 0.5
    sensors = root.find(f".//{{{DCC_NS}}}influenceCondition[@refType='chekan_angleSensors']")
    axes = {el.get("refType") for el in sensors.iter(f"{{{DCC_NS}}}list")}
    assert axes == {"chekan_angleSensor_x", "chekan_angleSensor_y"}


def test_budget_survives_an_svd_that_does_not_converge(monkeypatch):
    """LAPACK's SVD can fail on a Jacobian whose rows differ in scale by many orders: the
    budget then comes from the eigendecomposition, with the same numbers."""
    from chekan.fit import budget

    rng = np.random.default_rng(0)
    J = rng.normal(size=(40, 6)) * np.logspace(0, 3, 6)
    want = np.linalg.pinv(J.T @ J) @ J.T

    def fail(*a, **k):
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(budget.np.linalg, "pinv", fail)
    np.testing.assert_allclose(budget._influence(J), want, rtol=1e-8, atol=1e-14)


def test_x_rounds_tilt_about_x_and_hold_y_near_zero():
    prog = _program(rounds=2)
    rec, _ = simulate_session(prog, Truth(), seed=1)
    x_steps = [s.index for s in prog.steps if s.axis == "x" and s.kind == "tilt"]
    sel = np.isin(rec.step, x_steps)
    assert np.nanmax(np.abs(rec.tilt_x_arcsec[sel])) > 4.4 * 3600
    assert np.nanmax(np.abs(rec.tilt_y_arcsec[sel])) < 30


def test_posterior_predictive_of_a_two_axis_record_is_the_y_rounds_table(dual_fit):
    """bayes on a record with rounds about both axes crashed writing its predictive δg
    table (6 columns from all rounds against the 3 of the certified Y rounds): the
    replicated sessions go through the classical method as it reports, Y rounds only."""
    from chekan.classical.fit import calibrate_record
    from chekan.fit.predictive import posterior_predictive_delta_g
    from chekan.warmup import padded_model

    rec, truth, _res = dual_fit
    cres, holds = calibrate_record(rec, settle_s=120.0)
    model = padded_model(rec)  # as bayes fits it
    t = truth.derived()
    one = {
        "b1": t["b1"],
        "b2": t["b2"],
        "a": t["a"],
        "eps1_arcmin": t["eps1_arcmin"],
        "eps2_arcmin": t["eps2_arcmin"],
        "dgamma_arcmin": t["dgamma_arcmin"],
        "m_level_pix": np.asarray(truth.m_level_pix),
        "drift_coeffs": np.zeros((2, model.drift_degree)),
        "sigma_hold_pix": 0.05,
        "sigma_theta_arcsec": 1.0,
        "sigma1_pix": 0.1,
        "sigma2_pix": 0.1,
    }
    draws = {k: np.broadcast_to(np.asarray(v, float), (1, 4, *np.shape(v))) for k, v in one.items()}
    rep = posterior_predictive_delta_g(
        holds, rec.g_local_mgal, draws, model, np.random.default_rng(0)
    )
    assert rep.shape[1:] == np.asarray(cres.delta_g_mgal).shape  # (R_y, 2, n) of the Y rounds
    assert rep.shape[1] == 2  # 4 rounds alternating: 2 about Y
