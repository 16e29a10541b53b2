"""The expected ν_eff and k of a program (``chekan.design.reliability``) and the search's
choice by the expected U = k·sd."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from chekan import design as d
from chekan.design.reliability import ExpectedReliability, expected_reliability
from chekan.physics.program import build_program
from inference.dof import NU_CAP, coverage_factor, t_two_sided


def six_holds():
    """Two angles about X held once each (the designer's last-ranked program): every hold
    has its own systematic term and nothing tells a hold's random error from it."""
    return build_program([110 / 60, 310 / 60], axis="x", rounds=1, dwell_s=5486, settle_s=240)


def test_a_program_that_cannot_estimate_its_noise_gets_a_large_k():
    rel = expected_reliability(six_holds())
    # a's sd is the noise's, which six holds cannot estimate; b's is now mostly the Type B
    # of the pendulums' horizontal, which a program about X alone cannot tell from b
    # (chekan.joint.xresponse.level_angle_column), so its ν_eff is larger (≈ 6, was < 3)
    assert rel.nu_eff["a"] < 3 and rel.k["a"] > 4.0
    assert 3 < rel.nu_eff["b1"] < 20 and rel.k_of("b_mean") > 2.2
    assert set(rel.components) == {
        "noise_scale_1", "noise_scale_2", "slew_error", "sigma_theta", "sigma_hold",
    }  # fmt: skip


def test_more_rounds_more_degrees_of_freedom():
    """ν_eff of b grows with the holds that repeat a commanded angle; the paper's eight
    angles in two rounds (3 h) have well over a hundred (178 here; the MAP states 216–264
    on three simulated sessions of it, ``tests/test_design.py``)."""
    from chekan.demo import demo_program

    nus = [
        expected_reliability(
            build_program([2.5, 4.0, 5.0], rounds=r, dwell_s=400, settle_s=200)
        ).nu_eff["b1"]
        for r in (1, 2, 4)
    ]
    assert nus[0] < nus[1] < nus[2], nus
    paper = expected_reliability(demo_program(True))
    assert paper.nu_eff["b1"] > 100
    assert paper.k["b1"] == pytest.approx(coverage_factor(paper.nu_eff["b1"]))


def test_without_random_effects_only_the_noise_components_remain():
    vals = d.DesignValues(hold_offsets=False, angle_errors=False)
    rel = expected_reliability(build_program([2.5, 5.0], rounds=2, dwell_s=600), vals)
    assert rel.components == ("noise_scale_1", "noise_scale_2", "slew_error")
    # tens of thousands of samples inform the noise: ν_eff far beyond any table
    assert rel.nu_eff["b1"] > 1e3


def _fake(nu: float) -> ExpectedReliability:
    names = ("b1", "b2", "a", "b1_0", "b2_0")
    k = coverage_factor(nu)
    return ExpectedReliability({n: nu for n in names}, {n: k for n in names}, (), False)


def test_the_search_picks_the_smallest_expected_u_not_the_smallest_sd(monkeypatch):
    """With the smallest sd given k = t(1) (ν_eff 1) and every other program ν_eff 10⁶, the
    best is the next one by sd; the programs left unassessed could not have beaten it."""
    import chekan.design.search as search

    given = build_program([2.5, 4.0, 5.0], rounds=2, dwell_s=400, settle_s=200)
    space = {
        "n_angles": (3, 5),
        "spacing": ("dg",),
        "lowest_arcmin": (110,),
        "scheme": ("paper",),
        "rounds": (1, 2, 4),
        "settle_s": (120.0,),
    }
    first = d.search_programs(given, space=space, top=0)
    sd_best = next(c for c in first.ranked if first.fits(c))
    programs = {id(sd_best.program)}

    def fake(program, values=None):
        return _fake(1.0 if id(program) in programs else NU_CAP)

    monkeypatch.setattr(search, "expected_reliability", fake)
    res = replace(first, ranked=search.assess(
        [replace(c, reliability=None) for c in first.ranked], first.fits, d.DesignValues(), 0
    ))  # fmt: skip
    best = res.best
    assert best.program is not sd_best.program
    assert best.expected_u == pytest.approx(best.objective * coverage_factor(NU_CAP))
    flagged = next(c for c in res.ranked if c.program is sd_best.program)
    assert flagged.expected_u == pytest.approx(flagged.objective * t_two_sided(1, 0.9545))
    for c in res.ranked:
        if c.expected_u is None and res.fits(c):
            assert coverage_factor(math.inf) * c.objective >= best.expected_u


def test_design_command_warns_about_a_program_without_degrees_of_freedom(tmp_path, capsys):
    from chekan.cli.commands import main

    prog = tmp_path / "six.toml"
    prog.write_text(
        'name = "six"\nangles = ["1°50\'", "5°10\'"]\naxis = "x"\ndwell_s = 5486\n'
        "settle_s = 240\nrounds = 1\n",
        encoding="utf-8",
    )
    assert main(["design", str(prog)]) == 0
    text = capsys.readouterr().out
    assert "expected nu_eff" in text and "warning:" in text, text
