"""Systematic angle-sensor errors in the re-analysis of a legacy protocol (map)."""

import math

import numpy as np
import pytest

from chekan.joint.angles import AngleSensorSpec
from chekan.pipeline import CalibrationOptions, calibrate_file


def _map(path, **kw):
    return calibrate_file(path, CalibrationOptions(method="map", progress=False, **kw))


def _pure_scale(monkeypatch, bound=3.0):
    """Make the systematic spec a pure scale error (all of u² at θ_max)."""
    orig = CalibrationOptions.angle_spec

    def spec(self, meta, source="record"):
        if orig(self, meta, source) is None:
            return None
        return AngleSensorSpec(bound, scale_share=1.0)

    monkeypatch.setattr(CalibrationOptions, "angle_spec", spec)


def test_systematic_widens_b_and_has_its_budget_line(paper_protocol):
    ind = _map(paper_protocol, angle_errors="independent")
    sys_ = _map(paper_protocol)  # the default: systematic, 3″ from the paper
    assert ind["angle_sensor"] == {"model": "independent"}
    assert sys_["angle_sensor"]["model"] == "systematic"
    assert sys_["angle_sensor"]["bound_arcsec"] == 3.0
    for k in ("b1", "b2"):
        assert sys_["parameters"][k]["sd"] > ind["parameters"][k]["sd"]
        # the means move by much less than their sd
        assert (
            abs(sys_["parameters"][k]["mean"] - ind["parameters"][k]["mean"])
            < ind["parameters"][k]["sd"]
        )
        bud = sys_["uncertainty_budget"][k]
        assert "angle_systematic" not in ind["uncertainty_budget"][k]
        assert bud["angle_systematic"] > 0
        assert "angle_systematic_xy" not in bud  # one sensor: no common scale term
        footer = ("total", "nu_eff", "coverage_factor", "expanded")
        groups = [v for g, v in bud.items() if g not in footer]
        assert math.sqrt(sum(v * v for v in groups)) == pytest.approx(bud["total"], rel=1e-9)
        assert bud["total"] == pytest.approx(sys_["parameters"][k]["sd"])
        assert bud["expanded"] == pytest.approx(2 * bud["total"])  # ν_eff not evaluated


def test_pure_scale_prior_matches_analytic(paper_protocol, monkeypatch):
    """Δg ∝ θ², so a relative angle-scale error s moves b by 2s: sd(b) gains 2b·u/θ_max."""
    ind = _map(paper_protocol, angle_errors="independent")
    _pure_scale(monkeypatch)
    sys_ = _map(paper_protocol)
    theta_max = (5 + 10 / 60) * 3600.0  # the paper's largest angle, 5°10′, in arcsec
    u = AngleSensorSpec(3.0).u_arcsec  # all of u² on the scale term
    for k in ("b1", "b2"):
        expected = 2.0 * sys_["parameters"][k]["mean"] * u / theta_max
        s1, s0 = sys_["parameters"][k]["sd"], ind["parameters"][k]["sd"]
        assert math.sqrt(s1**2 - s0**2) == pytest.approx(expected, rel=0.2)
        assert sys_["uncertainty_budget"][k]["angle_systematic"] == pytest.approx(expected, rel=0.2)


def test_zero_bound_equals_independent(paper_protocol):
    ind = _map(paper_protocol, angle_errors="independent")
    zero = _map(paper_protocol, angle_bound_arcsec=0.0)
    for k in ("b1", "b2"):
        assert zero["parameters"][k]["mean"] == pytest.approx(
            ind["parameters"][k]["mean"], abs=1e-6
        )
        assert zero["parameters"][k]["sd"] == pytest.approx(ind["parameters"][k]["sd"], rel=1e-6)
    assert np.isfinite(zero["uncertainty_budget"]["b1"]["angle_systematic"])


def test_bound_from_the_protocol_header(paper_protocol, tmp_path):
    lines = paper_protocol.read_text(encoding="utf-8").splitlines(keepends=True)
    path = tmp_path / "p.csv"
    path.write_text(lines[0] + "# platform_angle_bound_arcsec: 6\n" + "".join(lines[1:]), "utf-8")
    wide = _map(path)
    base = _map(paper_protocol)
    assert wide["angle_sensor"]["bound_arcsec"] == 6.0
    for k in ("b1", "b2"):
        s6 = wide["uncertainty_budget"][k]["angle_systematic"]
        s3 = base["uncertainty_budget"][k]["angle_systematic"]
        assert s6 == pytest.approx(2 * s3, rel=0.05)  # linear in the bound
    # the option overrides the header
    assert _map(path, angle_bound_arcsec=3.0)["angle_sensor"]["bound_arcsec"] == 3.0
