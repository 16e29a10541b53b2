"""The pendulum's horizontal is the CCD centre only to a mounting tolerance: eq. (6) turns
the pendulum about its horizontal, so the X rounds' even response depends on where that
is (:func:`chekan.joint.xresponse.level_angle_column`), and the model carries it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from chekan.joint.xresponse import M0_TOLERANCE_PIX, level_angle_column, x_response_terms
from chekan.options import CalibrationOptions
from chekan.physics import sensor as fm
from chekan.physics.program import build_program
from chekan.pipeline import calibrate
from chekan.records.simulate import Truth, simulate_session

G_MGAL = 981_600.0


def _even_reading(m0_pix: float, m_level_pix: float, theta_rad: np.ndarray) -> np.ndarray:
    """(E(θ) + E(−θ))/2 about X of system 1 by the forward model, nominal b and K."""
    p = fm.make_params(
        g_mgal=G_MGAL,
        K_pix_per_rad=60428.0,
        b_mgal_per_pix=(6.9, 6.9),
        m_level_pix=(m_level_pix, m_level_pix),
        m0_pix=m0_pix,
    )
    zero = np.zeros_like(theta_rad)
    up = np.asarray(fm.equilibrium_readings(p, theta_rad, zero))[:, 0]
    down = np.asarray(fm.equilibrium_readings(p, -theta_rad, zero))[:, 0]
    return 0.5 * (up + down)


def test_level_angle_column_is_the_forward_models_even_response_to_the_horizontal():
    theta = np.deg2rad([0.0, 1.5, 2.5, 4.0, 5 + 10 / 60])
    for m_level in (1024.0, 1060.0):
        want = 0.5 * (_even_reading(1025.0, m_level, theta) - _even_reading(1023.0, m_level, theta))
        got = level_angle_column(theta, G_MGAL, m_level, 1024.0)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
        assert got[0] == 0.0
        # the pendulum turned in its own plane meets the stiffness g·sin θ·δ: to leading
        # order −(g/bK)²·sin²θ per pixel of the horizontal, 0.05 pix at 5°10′
        lead = -((G_MGAL / (6.9 * 60428.0)) ** 2) * np.sin(theta) ** 2
        np.testing.assert_allclose(got[1:], lead[1:], rtol=0.15)
    # linear over the tolerance: the column at ±100 pix is the column at the centre
    far = level_angle_column(theta, G_MGAL, 1024.0 + M0_TOLERANCE_PIX, 1024.0)
    np.testing.assert_allclose(far, level_angle_column(theta, G_MGAL, 1024.0, 1024.0), rtol=6e-3)


def test_level_angle_term_is_on_x_holds_and_x_slews_only_with_the_tolerance_as_prior():
    theta = np.deg2rad([0.0, 4.0, -4.0, 0.0, 5.0, -5.0])
    axis = np.array(["y", "y", "y", "x", "x", "x"])
    path = np.tile(np.deg2rad([1.0, 3.0]), (6, 1))
    path_on = np.zeros((6, 2), bool)
    path_on[4:] = True
    kinds = np.where(path_on.any(axis=1), 0, -1)
    hold, along, var = x_response_terms(
        theta, axis, G_MGAL, path, path_on, kinds, 1, m_level_pix=1030.0, m0_pix=1024.0
    )
    col, col_path = hold[:, -1], along[..., -1]
    assert var[-1] == M0_TOLERANCE_PIX**2
    # an instrument's own horizontal: the level column's prior, and nothing else, follows it
    *_, var_known = x_response_terms(
        theta, axis, G_MGAL, path, path_on, kinds, 1, m_level_pix=1030.0, m0_pix=1024.0,
        m0_u_pix=0.5,
    )  # fmt: skip
    assert var_known[-1] == 0.25
    np.testing.assert_array_equal(var_known[:-1], var[:-1])
    np.testing.assert_array_equal(col[:4], 0.0)  # level and Y holds: left out (16 ppm)
    np.testing.assert_allclose(col[4:], level_angle_column(theta[4:], G_MGAL, 1030.0, 1024.0))
    np.testing.assert_array_equal(col_path[:4], 0.0)
    np.testing.assert_allclose(
        col_path[4:], level_angle_column(path[4:], G_MGAL, 1030.0, 1024.0), rtol=1e-12
    )
    # a record about Y alone has no X terms at all
    h, a, v = x_response_terms(
        theta[:3],
        axis[:3],
        G_MGAL,
        path[:3],
        path_on[:3] & False,
        kinds[:3],
        0,
        m_level_pix=1030.0,
        m0_pix=1024.0,
    )
    assert h.shape == (3, 0) and a.shape == (3, 2, 0) and v.size == 0


@pytest.mark.slow
def test_a_pendulum_horizontal_far_from_the_ccd_centre_keeps_a_honest():
    """Rounds about both axes on a platform whose sensors are known to 0.5″: with the
    horizontal 40 pix off the centre that the record states (both systems alike, so that
    their effects on the shared a add), a stays within its interval: without the level
    angle term it was 8.8 sd off (b₁ 2.0 sd), with it 0.3 sd."""
    prog = build_program([2.5, 4.0, 5 + 10 / 60], axis="xy", rounds=4, dwell_s=300, settle_s=120)
    truth = Truth(
        angle_systematic_arcsec=0.0,
        angle_error_sd_arcsec=0.3,
        horizontal_offset_pix=(40.0, 40.0),
        drift_pix_per_h=(0.0, 0.0),
        drift_pix_per_h2=(0.0, 0.0),
    )
    rec, truth = simulate_session(prog, truth, seed=7)
    assert rec.ccd_center_pix == 1024.0  # the record states the centre, not the horizontal
    meta = {
        **rec.meta,
        "platform_angle_bound_x_arcsec": "0.5",
        "platform_angle_bound_y_arcsec": "0.5",
    }
    res = calibrate(
        dataclasses.replace(rec, meta=meta), CalibrationOptions(method="map", progress=False)
    )
    t = truth.derived()
    for name in ("b1", "b2", "a"):
        p = res["parameters"][name]
        assert abs(p["mean"] - t[name]) < 2.5 * p["sd"], (name, p, t[name])
    assert res["diagnostics"]["converged"]


def test_the_horizontal_case_moves_the_pendulums_not_the_stated_centre():
    from chekan.study.coverage import CASES, X_CASES
    from chekan.study.scenario import Scenario, session_truth

    assert "horizontal" in CASES and "horizontal" in X_CASES
    offs = np.array(
        [
            session_truth(
                "horizontal", np.random.default_rng(i), i, Scenario()
            ).horizontal_offset_pix
            for i in range(40)
        ]
    )
    assert np.all(np.abs(offs) <= M0_TOLERANCE_PIX) and np.abs(offs).max() > 0.8 * M0_TOLERANCE_PIX
    assert session_truth(
        "typical", np.random.default_rng(1), 1, Scenario()
    ).horizontal_offset_pix == (
        0.0,
        0.0,
    )
    truth = Truth(horizontal_offset_pix=(30.0, -20.0))
    prog = build_program([4.0], axis="x", rounds=1, dwell_s=60, settle_s=30)
    rec, _ = simulate_session(prog, truth, seed=1)
    assert rec.meta["ccd_center_pix"] == "1024"
    # the pendulums turn about their own horizontal: the X response differs from a centred one
    centred, _ = simulate_session(prog, Truth(), seed=1)
    assert np.max(np.abs(rec.m1_pix - centred.m1_pix)) > 1.0


def test_a_is_taken_at_the_pendulums_horizontal():
    """a(m_h) = G''(φ_h)/(2K²) depends on where the horizontal is (≈ 14 ppm per pixel):
    the estimate takes it at m₀ + Δm₀ⱼ, the truth of a simulated horizontal offset is the
    same number, and b₀ stays at the CCD centre."""
    from chekan.joint.derived import at_horizontal, at_level

    centred = Truth()
    off = dataclasses.replace(centred, horizontal_offset_pix=(40.0, -20.0))
    sp = centred.params()
    a0, b00 = at_level(sp)
    a_same, b0_same = at_horizontal(sp, np.zeros(2))
    assert float(a_same) == pytest.approx(float(a0), rel=1e-14)
    np.testing.assert_allclose(np.asarray(b0_same), np.asarray(b00), rtol=1e-14)
    a_off, b0_off = at_horizontal(sp, np.array([40.0, -20.0]))
    t = off.derived()
    assert float(a_off) == pytest.approx(t["a"], rel=1e-12)
    assert float(a_off) != pytest.approx(float(a0), rel=1e-4)  # it moves (here −144 ppm)
    np.testing.assert_allclose(np.asarray(b0_off), [t["b1_0"], t["b2_0"]], rtol=1e-12)


def test_the_designer_takes_a_at_the_horizontal_as_the_estimate_does():
    """The designer's a carries the horizontal's uncertainty as the estimate's does: its
    gradient in Δm₀ⱼ is that of a(m_h) at the shifted horizontal (a central difference of
    :func:`chekan.joint.derived.at_horizontal`); on a program about X a's expected sd is
    the delta method over (θ, c, Δm₀), a fraction of a per cent above the one over (θ, c)
    (the rounds measure Δm₀ well), and a program about Y alone has no Δm₀."""
    import scipy.linalg

    from chekan.design.information import (
        DesignValues,
        expected_precision,
        information_blocks,
        sensitivities,
    )
    from chekan.joint.derived import at_horizontal

    truth = Truth()
    grad = sensitivities(truth, "y").derived_grad
    sp = truth.params()
    for j in range(2):
        step = np.zeros(2)
        step[j] = 1.0
        up, down = at_horizontal(sp, step), at_horizontal(sp, -step)
        want = (float(up[0]) - float(down[0])) / 2.0
        assert grad[0, 8 + j] == pytest.approx(want, rel=1e-5)
    kw = {"dwell_s": 200.0, "settle_s": 120.0, "rounds": 2}
    xy = build_program([3.0, 4.0, 5 + 10 / 60], axis="xy", order="alternate", **kw)
    Mgg, Mgb, ab, _, _, level = information_blocks(xy, DesignValues())
    assert level.size == 2
    cov = np.linalg.inv(Mgg - Mgb @ scipy.linalg.solveh_banded(ab, Mgb.T))
    J = np.zeros(cov.shape[0])
    J[:6], J[7:9] = grad[0, :6], grad[0, 6:8]
    at_level_sd = float(np.sqrt(J @ cov @ J))
    J[level] = grad[0, 8:10]
    at_horizontal_sd = float(np.sqrt(J @ cov @ J))
    assert expected_precision(xy).sd["a"] == pytest.approx(at_horizontal_sd, rel=1e-8)
    assert 1.0 < at_horizontal_sd / at_level_sd < 1.05
    y = build_program([3.0, 4.0, 5 + 10 / 60], **kw)
    assert information_blocks(y, DesignValues())[-1].size == 0
