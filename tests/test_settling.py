"""The lag in the hold means (``chekan.classical.settling``): where a program's settling time is
short
beside τ, the classical method is told that its items are biased, and a joint result's
items are computed from the hold means with the transient removed; the verdict judges the
certified b. The truth stands in for the joint fit (no MAP to compile)."""

from __future__ import annotations

import copy
import dataclasses
import re

import numpy as np
import pytest

from chekan.classical.settling import (
    UNSETTLED_PIX,
    raw_transient_pix,
    tau_from_transients,
    transient_bound_pix,
    unsettled_transient_pix,
)
from chekan.options import CalibrationOptions
from chekan.physics.program import build_program
from chekan.pipeline import calibrate
from chekan.records.holds import segment_record
from chekan.records.simulate import Truth, simulate_session
from chekan.results.document import certified_instability, settled_items

PROGRAM = build_program(
    [2.5, 3.5, 4.5, 5 + 10 / 60], name="short-settle", axis="y", rounds=2, dwell_s=194.0,
    settle_s=120.0,
)  # fmt: skip
TRUTH = Truth(tau_s=45.0, angle_systematic_arcsec=0.0, tilt_jitter_arcsec=0.0)


def _as_fitted(classical: dict, truth: Truth) -> dict:
    """The classical result with the truth as its joint estimate (b, a, ε, Δγ, τ)."""
    g = truth.g_local_mgal
    mean = {"b1": truth.b_mgal_per_pix[0], "b2": truth.b_mgal_per_pix[1],
            "a": g / (2.0 * truth.K_pix_per_rad**2),  # eq. 13: a = g/(2K²)
            "eps1_arcmin": truth.eps_arcmin[0], "eps2_arcmin": truth.eps_arcmin[1],
            "dgamma_arcmin": truth.dgamma_arcmin, "tau_s": truth.tau_s}  # fmt: skip
    return {
        **classical,
        "method": "map",
        "parameters": {k: {"mean": v, "sd": 0.0} for k, v in mean.items()},
        "level_reading_pix": {"m1": truth.m_level_pix[0], "m2": truth.m_level_pix[1]},
        "classical": {k: classical["parameters"][k] for k in ("b1", "b2")},
        "b_prior": {"b1": 7.0, "b2": 6.9},
    }


@pytest.fixture(scope="module")
def unsettled():
    rec, truth = simulate_session(PROGRAM, TRUTH, seed=7)
    holds = segment_record(rec, settle_s=120.0)
    classical = calibrate(rec, CalibrationOptions(method="classical", progress=False))
    return rec, truth, holds, classical


def test_the_transient_is_read_alike_from_the_readings_and_from_the_model(unsettled):
    """τ read off the transients, the transient each hold mean keeps by the readings alone,
    and its cheap bound agree with the model's (the truth, lag followed through the record)."""
    rec, truth, holds, classical = unsettled
    tau = tau_from_transients(rec, holds)
    assert abs(tau / truth.tau_s - 1.0) < 0.05
    model = unsettled_transient_pix(_as_fitted(classical, truth), holds, rec)
    raw = raw_transient_pix(holds, rec, tau)
    tilt = ~holds.is_level
    assert np.nanmax(np.abs(model)) > 1.0  # 120 s settling at τ 45 s: pixels left
    gap = np.abs(raw[tilt] - model[tilt])
    assert np.all(gap < 0.05 + 0.05 * np.abs(model[tilt])), gap.max()
    assert transient_bound_pix(holds, rec, truth.tau_s) >= np.nanmax(np.abs(model))


def test_the_classical_method_flags_unsettled_hold_means_and_not_settled_ones(unsettled):
    _rec, truth, _holds, classical = unsettled
    (problem,) = [p for p in classical["diagnostics"]["problems"] if "transients" in p]
    assert "settling time 120 s" in problem and "τ ≈ 45 s" in problem
    b_raw = classical["parameters"]["b1"]["mean"]
    assert abs(b_raw / truth.b_mgal_per_pix[0] - 1.0) > 1e-3  # biased by the transient
    # the problem states the b without the transient (read off the record): near the truth
    without = float(re.search(r"b1 [+-][\d.]+ % \([\d.]+ sd; ([\d.]+) without\)", problem)[1])
    assert abs(without / truth.b_mgal_per_pix[0] - 1.0) < 3e-4 < abs(b_raw / without - 1.0)
    un = classical["unsettled_hold_means"]  # the same, as numbers
    assert un["b_without"][0] == pytest.approx(without, abs=5e-7) and un["shift_sd"][0] > 1.0
    # the method's precondition fails: the certificate's verdict says so
    from chekan.report.content import verdict_of

    passed, line = verdict_of(classical)
    assert passed is False and "the hold means are NOT settled (up to" in line
    fast, _ = simulate_session(PROGRAM, dataclasses.replace(TRUTH, tau_s=8.0), seed=7)
    settled = calibrate(fast, CalibrationOptions(method="classical", progress=False))
    assert not any("transients" in p for p in settled["diagnostics"].get("problems", []))
    assert "unsettled_hold_means" not in settled
    assert "NOT settled" not in verdict_of(settled)[1]


def test_the_live_pages_classical_preview_notes_unsettled_hold_means(unsettled):
    """The live page's classical preview takes the hold means as Calibr.exe does; it says
    when they are unsettled (and not otherwise), and the page shows it among its alarms."""
    from chekan.live.calib import classical_snapshot

    rec, *_ = unsettled
    assert "slews' transients" in classical_snapshot(rec, settle_s=120.0)["unsettled"]
    fast, _ = simulate_session(PROGRAM, dataclasses.replace(TRUTH, tau_s=8.0), seed=7)
    assert classical_snapshot(fast, settle_s=120.0)["unsettled"] is None


def test_a_joint_results_items_come_from_settled_hold_means(unsettled, monkeypatch):
    """The items (b, reduced error) from the hold means less the model's transient lie at
    the truth where the raw ones are biased; Calibr.exe's raw figures are kept beside them."""
    rec, truth, holds, classical = unsettled
    fitted = _as_fitted(classical, truth)
    before = copy.deepcopy(fitted)
    out = settled_items(fitted, holds, rec)
    assert fitted == before  # what it is handed is not changed
    assert "unsettled_hold_means" in fitted and "unsettled_hold_means" not in out
    ht = out["hold_transient"]
    assert ht["max_pix"] > 1.0 and ht["tau_s"] == truth.tau_s and ht["settle_s"] == 120.0
    raw = ht["calibr_exe"]
    assert raw["b1"] == classical["parameters"]["b1"]
    assert raw["reduced_error_percent"] == classical["reduced_error_percent"]
    for s, name in enumerate(("b1", "b2")):
        b_true = truth.b_mgal_per_pix[s]
        before = abs(classical["parameters"][name]["mean"] / b_true - 1.0)
        after = abs(out["classical"][name]["mean"] / b_true - 1.0)
        assert after < 2e-4 < before, (name, before, after)
    assert out["reduced_error_percent"] < classical["reduced_error_percent"]
    assert out["residuals_mgal"] != classical["residuals_mgal"]
    assert [r["b1"]["mean"] for r in out["rounds"]] != [
        r["b1"]["mean"] for r in classical["rounds"]
    ]
    # the certificate says so, with Calibr.exe's raw figures, and no longer warns of a bias
    from chekan.report.content import settled_note, transient_note
    from chekan.report.i18n import tr

    (note,) = settled_note(out, tr("en"))
    assert f"up to {ht['max_pix']:.2f} pix" in note.text and "τ = 45.0 s" in note.text
    assert f"b₁ = {raw['b1']['mean']:.6f}" in note.text
    assert f"reduced error {raw['reduced_error_percent']:.3f} %" in note.text
    from chekan.results.summary import format_summary

    assert f"as Calibr.exe: b1 = {raw['b1']['mean']:.6f} mGal/pix" in format_summary(out)
    transient = unsettled_transient_pix(fitted, holds, rec)
    assert transient_note(fitted, holds, transient, tr("en"))  # a result without settling
    assert transient_note(out, holds, transient, tr("en")) == []
    # a fit that did not converge has no transient to trust: Calibr.exe's items stay
    lost = {**fitted, "diagnostics": {**fitted["diagnostics"], "converged": False}}
    assert settled_items(lost, holds, rec) == certified_instability(lost)
    # … and where its input lacks the classical fit's flag, the classical fit gives it
    from chekan.classical.fit import calibrate_record

    bare = {k: v for k, v in lost.items() if k != "unsettled_hold_means"}
    cres, _ = calibrate_record(rec, settle_s=120.0)
    flagged = settled_items(bare, holds, rec, classical=cres)
    assert flagged["unsettled_hold_means"] == classical["unsettled_hold_means"]
    # nor is a calibration lost where the settled refit fails: the raw items and their flag
    import chekan.classical.fit
    from chekan.errors import ChekanError

    def refuse(*args, **kwargs):
        raise ChekanError("no fit")

    monkeypatch.setattr(chekan.classical.fit, "fit_by_axis", refuse)
    assert settled_items(fitted, holds, rec) == certified_instability(fitted)
    monkeypatch.undo()
    # the instability is the certified b's (the truth here), not the classical one's
    assert out["instability_percent"]["b1"] == pytest.approx(
        (truth.b_mgal_per_pix[0] - 7.0) / 7.0 * 100.0, rel=1e-12
    )


def test_the_settled_items_do_not_depend_on_the_lag(unsettled):
    """The same platform and noise (the seed) with a sensor twice as slow: Calibr.exe's b
    moves with τ, the settled items' b does not (it is the instrument's, not the program's)."""
    rec, truth, holds, classical = unsettled
    slow_rec, slow = simulate_session(PROGRAM, dataclasses.replace(TRUTH, tau_s=90.0), seed=7)
    slow_holds = segment_record(slow_rec, settle_s=120.0)
    slow_cl = calibrate(slow_rec, CalibrationOptions(method="classical", progress=False))
    fast = settled_items(_as_fitted(classical, truth), holds, rec)
    slow_out = settled_items(_as_fitted(slow_cl, slow), slow_holds, slow_rec)
    assert slow_out["hold_transient"]["max_pix"] > 5 * fast["hold_transient"]["max_pix"]
    for name in ("b1", "b2"):
        raw = [classical["parameters"][name]["mean"], slow_cl["parameters"][name]["mean"]]
        settled = [fast["classical"][name]["mean"], slow_out["classical"][name]["mean"]]
        assert abs(raw[1] / raw[0] - 1.0) > 1e-2  # the raw b moves by percents
        sd = classical["parameters"][name]["sd"] / settled[0]  # ≈ 3e-4 relative
        assert abs(settled[1] / settled[0] - 1.0) < min(1e-4, 0.5 * sd), (settled, sd)


def test_settled_hold_means_leave_the_items_as_calibr_exe_computes_them():
    """τ short beside the settling time: nothing to remove, the items are Calibr.exe's; the
    instability is still the certified b's."""
    truth = dataclasses.replace(TRUTH, tau_s=8.0)
    rec, truth = simulate_session(PROGRAM, truth, seed=7)
    holds = segment_record(rec, settle_s=120.0)
    classical = calibrate(rec, CalibrationOptions(method="classical", progress=False))
    fitted = _as_fitted(classical, truth)
    assert np.nanmax(np.abs(unsettled_transient_pix(fitted, holds, rec))) < UNSETTLED_PIX
    out = settled_items(fitted, holds, rec)
    assert "hold_transient" not in out
    assert out == certified_instability(fitted)
    assert out["instability_percent"]["b2"] == pytest.approx(
        (truth.b_mgal_per_pix[1] - 6.9) / 6.9 * 100.0, rel=1e-12
    )


def test_the_designer_predicts_the_transient_a_record_of_the_program_carries(
    unsettled, tmp_path, capsys
):
    """``chekan design`` states what a program's settling leaves in the hold means at the
    design τ, and up to which τ the classical items hold: the same transient as a simulated
    record of the program carries (the model with the lag followed through it)."""
    import json

    from chekan.cli.commands import main
    from chekan.design.command import program_toml
    from chekan.design.information import settled_tau_limit_s, settled_transient_pix
    from chekan.design.layout import DesignValues

    rec, truth, holds, classical = unsettled
    want = np.nanmax(np.abs(unsettled_transient_pix(_as_fitted(classical, truth), holds, rec)))
    values = DesignValues(truth=truth)
    assert settled_transient_pix(PROGRAM, values) == pytest.approx(want, rel=0.02)
    limit = settled_tau_limit_s(PROGRAM, values)
    for tau, settled in ((limit, True), (limit * 1.02, False)):
        at = DesignValues(truth=dataclasses.replace(truth, tau_s=tau))
        assert (settled_transient_pix(PROGRAM, at) <= UNSETTLED_PIX) is settled, tau
    toml, out = tmp_path / "short.toml", tmp_path / "design.json"
    toml.write_text(program_toml(PROGRAM), encoding="utf-8")
    assert main(["design", str(toml), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "classical items (--method classical, as Calibr.exe): the 120 s settling" in text
    assert "they are biased by it where map and bayes remove it" in text
    s = json.loads(out.read_text(encoding="utf-8"))["given"]["classical_settling"]
    assert s["settle_s"] == 120.0 and s["transient_pix"] > 1.0 and 1.0 < s["tau_limit_s"] < 45
