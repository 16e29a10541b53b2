"""A fit whose hyperparameters end at a bound is flagged (issue 33 §3): in the result's
diagnostics.problems, on the console, on the certificate; --strict exits 3 on it. Typical
simulated sessions are not flagged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from chekan.cli.commands import main
from chekan.records import write_record
from chekan.records.simulate import Truth, random_truth, simulate_session


@pytest.fixture(scope="module")
def flawless(short_program, tmp_path_factory):
    """A session without angle errors or hold offsets: σ_θ and σ_o have nothing to
    estimate and end at the EM's lower bounds."""
    truth = Truth(
        angle_error_sd_arcsec=0.0,
        angle_systematic_arcsec=0.0,
        tilt_jitter_arcsec=0.0,
        hold_offset_sd_pix=0.0,
    )
    rec, _ = simulate_session(short_program, truth, seed=3)
    path = tmp_path_factory.mktemp("flags") / "rec.csv"
    write_record(path, rec)
    return path


def test_a_hyperparameter_at_its_bound_is_flagged_and_strict_exits_3(flawless, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["calibrate", str(flawless), "--method", "map", "--json", str(out)]) == 0
    console = capsys.readouterr().out
    problems = json.loads(out.read_text())["diagnostics"]["problems"]
    assert any("σ_θ" in p and "lower bound" in p for p in problems), problems
    assert "σ_θ" in console and "lower bound" in console
    from chekan.report.content import build_report

    assert "lower bound" in repr(build_report(json.loads(out.read_text()), figures=False))
    assert main(["calibrate", str(flawless), "--method", "map", "--strict", "-q"]) == 3


def test_typical_sessions_are_not_flagged(short_program):
    from chekan.options import CalibrationOptions
    from chekan.pipeline import calibrate

    for i in range(3):
        rec, _ = simulate_session(short_program, random_truth(np.random.default_rng(i)), seed=i)
        r = calibrate(rec, CalibrationOptions(method="map", progress=False))
        assert r["diagnostics"]["problems"] == [], (i, r["diagnostics"]["problems"])


def test_residuals_the_model_does_not_describe_are_flagged(short_program, tmp_path, capsys):
    """An effect the model leaves out (here a 0.6 pix oscillation of system 1 with a 25 min
    period, which the cubic drift cannot follow) leaves residuals several times the
    samples' own scatter: flagged, and --strict exits 3 (issue 33 §3)."""
    import dataclasses

    rec, _ = simulate_session(short_program, random_truth(np.random.default_rng(0)), seed=0)
    wavy = dataclasses.replace(rec, m1_pix=rec.m1_pix + 0.6 * np.sin(2 * np.pi * rec.t_s / 1500))
    path = tmp_path / "wavy.csv"
    write_record(path, wavy)
    out = tmp_path / "r.json"
    assert main(["calibrate", str(path), "--method", "map", "--json", str(out), "-q"]) == 0
    problems = json.loads(out.read_text())["diagnostics"]["problems"]
    assert any("residuals of system 1" in p for p in problems), problems
    assert not any("residuals of system 2" in p for p in problems), problems
    assert main(["calibrate", str(path), "--method", "map", "--strict", "-q"]) == 3
