"""Systematic angle-sensor errors: constructed cases in which the stated sd must grow.

A systematic error repeats in every round, so the data cannot reveal it and agreement
between rounds says nothing about it: its uncertainty reaches b only through the prior
from the platform's specification (GUM Type B). These tests check the stated sd against
what that prior implies analytically.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from chekan import joint
from chekan.classical import calibrate_record
from chekan.errors import ChekanError
from chekan.joint.angles import AngleSensorSpec, commanded_groups, spec_for, systematic_basis
from chekan.joint.derived import map_derived
from chekan.program import build_program
from chekan.simulate import Truth, simulate_session
from chekan.units import ARCSEC_PER_RAD


def _sd_b(rec, settle_s, spec):
    cres, _ = calibrate_record(rec, settle_s=settle_s)
    _, model = joint.prepare(rec, settle_s, angle_spec=spec)
    fit = joint.fit_map_em(model, joint.initial_values(cres, rec.g_local_mgal))
    assert fit.result.converged
    md = map_derived(fit)
    return md["b1"], md["b2"]


def test_spec_reads_the_bound_as_rectangular_by_default_and_from_the_header():
    spec = AngleSensorSpec(3.0)  # rectangular: u = U/√3 (GUM 4.3.7, only a bound known)
    assert spec.u_arcsec == pytest.approx(3.0 / math.sqrt(3.0))
    assert spec.per_angle_var + spec.scale_var == pytest.approx(3.0)
    assert "GUM 4.3.7" in spec.reading
    tri = AngleSensorSpec(3.0, distribution="triangular")  # u = U/√6 (GUM 4.3.9)
    assert tri.per_angle_var + tri.scale_var == pytest.approx(1.5)
    assert spec_for({}, None) == AngleSensorSpec()
    assert "paper" in spec_for({}, None).source
    assert spec_for({"platform_angle_bound_arcsec": "2"}, None).bound_arcsec == 2.0
    assert spec_for({"platform_angle_bound_arcsec": "2"}, 1.0).bound_arcsec == 1.0
    # a bound per axis: the axis's own key before the common one
    meta = {"platform_angle_bound_arcsec": "2", "platform_angle_bound_y_arcsec": "1.5"}
    assert spec_for(meta, None, axis="y").bound_arcsec == 1.5
    assert spec_for(meta, None, axis="x").bound_arcsec == 2.0
    assert "platform_angle_bound_y_arcsec" in spec_for(meta, None, "r.csv", axis="y").source
    with pytest.raises(ChekanError, match=r"rec\.csv: platform_angle_bound_arcsec"):
        spec_for({"platform_angle_bound_arcsec": "two"}, None, "rec.csv")
    with pytest.raises(ChekanError, match="≥ 0"):
        AngleSensorSpec(-1.0)


def test_commanded_angles_are_grouped_across_rounds():
    deg = np.deg2rad([0, 2, -2, 5, -5, 0, 2, -2, 5, -5, 0])
    jitter = np.random.default_rng(0).normal(0, 2.0, deg.size) / ARCSEC_PER_RAD
    g = commanded_groups(deg + jitter)
    assert g.max() + 1 == 5  # level, ±2°, ±5°
    assert g[1] == g[6] and g[3] == g[8] and g[0] == g[5] == g[10]
    basis, var = systematic_basis(deg, AngleSensorSpec(3.0))
    assert basis.shape == (11, 6)
    np.testing.assert_allclose(basis[:, -1], deg / deg.max())  # the scale column
    np.testing.assert_allclose(var, [1.5] * 5 + [1.5])  # u² = 3²/3, half each


@pytest.mark.slow
def test_pure_scale_error_adds_two_u_over_theta_max_in_quadrature(short_program):
    """A scale error ξ·θ/θ_max of the angle sensor acts on b one to one: Δg ∝ θ², so
    δb/b = −2ξ/θ_max. With a pure scale prior of sd u the stated sd must grow by
    2·b·u/θ_max in quadrature (the data cannot see ξ: it repeats in every round)."""
    rec, truth = simulate_session(
        short_program, Truth(serial="S", angle_systematic_arcsec=0.0), seed=21
    )
    settle = short_program.settle_s
    bound = 3.0
    (_, sd0), _ = _sd_b(rec, settle, None)
    spec = AngleSensorSpec(bound, scale_share=1.0)
    (_, sd1), _ = _sd_b(rec, settle, spec)
    theta_max = max(abs(s.tilt_y_rad) for s in short_program.steps) * ARCSEC_PER_RAD
    expected = 2 * truth.b_mgal_per_pix[0] * spec.u_arcsec / theta_max
    added = math.sqrt(sd1**2 - sd0**2)
    assert added == pytest.approx(expected, rel=0.2), (sd0, sd1, added, expected)


@pytest.mark.slow
def test_per_angle_error_does_not_average_over_rounds():
    """Errors per commanded angle repeat in every round: the part of var(b) they bring
    does not fall with the number of rounds, however well the rounds agree."""
    added = {}
    for rounds in (2, 6):
        prog = build_program([2.0, 3.5, 5.0], dwell_s=300, settle_s=200, rounds=rounds)
        rec, _ = simulate_session(prog, Truth(serial="P", angle_systematic_arcsec=0.0), seed=4)
        (_, sd0), _ = _sd_b(rec, 200, None)
        (_, sd1), _ = _sd_b(rec, 200, AngleSensorSpec(3.0, scale_share=0.0))
        added[rounds] = sd1**2 - sd0**2
    assert added[2] > 0 and added[6] / added[2] > 0.75  # the systematic part stays
