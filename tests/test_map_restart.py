"""The MAP's first pass restarts from other lag time constants when it lands in the prior's
tails: a short one-round session with a fast lag (τ = 5 s) walked into a mode where the
holds never settle, and reported b ≈ 0.3 mGal/pix as its answer."""

from __future__ import annotations

import numpy as np

from chekan.fit import map as jmap


def test_short_session_with_a_fast_lag_finds_the_truth(tmp_path):
    from chekan.archive.synth import short_program
    from chekan.options import CalibrationOptions
    from chekan.pipeline import calibrate_file
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session

    rec, truth = simulate_session(short_program(), Truth(serial="T-5", tau_s=5.0), seed=1)
    path = tmp_path / "fast.csv"
    write_record(path, rec)
    r = calibrate_file(path, CalibrationOptions(method="map", progress=False))
    p, d = r["parameters"], r["diagnostics"]
    assert d["converged"], d["problems"]
    for j in range(2):
        got = p[f"b{j + 1}"]
        assert abs(got["mean"] - truth.b_mgal_per_pix[j]) < 4 * got["sd"], got
    assert abs(p["tau_s"]["mean"] / 5.0 - 1) < 0.2, p["tau_s"]


class _Res:
    def __init__(self, z, cost, converged=True):
        self.z, self.cost, self.converged = np.asarray(z, float), cost, converged


class _Space:
    def prior_residuals(self, z):
        return z  # z is the prior z-score in this fake

    def to_z(self, values):
        return np.array([values["tau_s"]])


class _Prob:
    map_space = _Space()
    lsq = None


NAN = float("nan")
# (record, τ₀, solver) -> (z = prior z-score, cost, converged)
_PASSES = {
    ("bulk", 30.0, "gn"): ([0.5], 1.0, True),  # inside the prior: kept, never restarted
    ("tails", 30.0, "gn"): ([7.0], 50.0, True),  # in the tails: restarted
    ("tails", 5.0, "gn"): ([0.0], 10.0, True),  # gains 40: replaces it
    ("tails", 120.0, "gn"): ([0.0], 9.5, True),  # gains 0.5 on 10: does not
    ("same", 30.0, "gn"): ([7.0], 50.0, True),
    ("same", 5.0, "gn"): ([0.0], 49.5, True),  # the same mode again: keeps the first
    ("same", 120.0, "gn"): ([0.0], 49.5, True),
    ("fails", 30.0, "gn"): ([0.0], NAN, False),  # GN fails from τ₀ = 30 s ...
    ("fails", 5.0, "gn"): ([0.0], 12.0, True),  # ... and converges from 5 s: no LM at all
    ("fails", 120.0, "gn"): ([0.0], NAN, False),
    ("none", 30.0, "gn"): ([0.0], NAN, False),  # no start converges inside the prior:
    ("none", 5.0, "gn"): ([9.0], 30.0, True),
    ("none", 120.0, "gn"): ([0.0], NAN, False),
    ("none", 30.0, "lm"): ([1.0], 20.0, True),  # LM from the starts where GN failed
    ("none", 120.0, "lm"): ([1.0], 19.5, True),
    ("hinted", 30.0, "gn"): ([7.0], 50.0, True),  # in the tails; its own τ (5.2 s) ...
    ("hinted", 5.2, "gn"): ([0.0], 10.0, True),  # ... lands in the bulk: no other restart
    ("hintbad", 30.0, "gn"): ([7.0], 50.0, True),
    ("hintbad", 100.0, "gn"): ([8.0], 40.0, True),  # its hint's pass is in the tails too:
    ("hintbad", 5.0, "gn"): ([0.0], 10.0, True),  # 5 s is tried, 120 s (within 1.5× of 100) not
}


def _fake_solve(calls: list, passes: dict = _PASSES):
    def solve(lsq, args, z, solver):
        calls.append((args, float(z[0]), solver))
        return _Res(*passes[(args, float(z[0]), solver)])

    return solve


def _first_pass(record, solver="gn", hint=None):
    return jmap._first_pass(_Prob(), record, {"tau_s": 30.0}, solver, hint)


def test_first_pass_restarts_only_a_record_in_the_tails(monkeypatch):
    """A record inside the prior is never restarted. One in the tails is solved again from
    each restart τ with the fit's solver; a restart replaces the first pass only if it
    lowers the cost by more than RESTART_GAIN (the same mode found again keeps its
    numbers)."""
    calls: list = []
    monkeypatch.setattr(jmap, "_solve", _fake_solve(calls))
    got = [_first_pass(r) for r in ("bulk", "tails", "same")]
    assert calls == [
        ("bulk", 30.0, "gn"),
        ("tails", 30.0, "gn"),
        ("tails", 5.0, "gn"),
        ("tails", 120.0, "gn"),
        ("same", 30.0, "gn"),
        ("same", 5.0, "gn"),
        ("same", 120.0, "gn"),
    ]
    assert [r.cost for r, _ in got] == [1.0, 10.0, 50.0]
    assert [s for _, s in got] == ["gn", "gn", "gn"]


def test_first_pass_runs_lm_only_where_no_start_converged_in_the_prior(monkeypatch):
    """Levenberg–Marquardt, the fallback of a Gauss–Newton pass that did not converge, runs
    only for a record where no start gave a converged pass inside the prior's bulk, and only
    from the starts where Gauss–Newton failed; a converged pass beats a failed one."""
    calls: list = []
    monkeypatch.setattr(jmap, "_solve", _fake_solve(calls))
    fails, solver = _first_pass("fails")
    assert [c[2] for c in calls] == ["gn", "gn", "gn"]  # GN from the three starts, no LM
    assert fails.cost == 12.0 and solver == "gn"
    calls.clear()
    none, solver = _first_pass("none")
    assert calls[3:] == [("none", 30.0, "lm"), ("none", 120.0, "lm")]
    assert len(calls) == 5
    assert none.cost == 20.0 and solver == "lm"  # 19.5 gains only 0.5


def test_first_pass_with_lm_restarts_with_lm(monkeypatch):
    """``map_solver="lm"``: the restarts use LM too, and there is no other fallback."""
    calls: list = []
    passes = {(r, t, "lm"): v for (r, t, s), v in _PASSES.items() if s == "gn"}
    monkeypatch.setattr(jmap, "_solve", _fake_solve(calls, passes))
    result, solver = _first_pass("tails", "lm")
    assert [c[2] for c in calls] == ["lm", "lm", "lm"]
    assert result.cost == 10.0 and solver == "lm"


def test_a_records_own_tau_is_tried_first_and_spares_the_other_restarts(monkeypatch):
    """The pipeline's τ hint (read off the transients) is the first restart: where its pass
    lands in the prior's bulk no fixed restart runs; where it does not, the fixed restarts
    follow, skipping a τ within RESTART_APART of one tried. A record inside the prior is
    never restarted and its hint function is never called."""
    calls: list = []
    monkeypatch.setattr(jmap, "_solve", _fake_solve(calls))

    def never() -> float:
        raise AssertionError("the hint of a record that needs no restart was read")

    got = [
        _first_pass("bulk", hint=never),
        _first_pass("hinted", hint=lambda: 5.2),
        _first_pass("hintbad", hint=100.0),
    ]
    assert calls == [
        ("bulk", 30.0, "gn"),
        ("hinted", 30.0, "gn"),
        ("hinted", 5.2, "gn"),
        ("hintbad", 30.0, "gn"),
        ("hintbad", 100.0, "gn"),
        ("hintbad", 5.0, "gn"),
    ]
    assert [r.cost for r, _ in got] == [1.0, 10.0, 10.0]
    assert [s for _, s in got] == ["gn", "gn", "gn"]


def test_tau_read_off_the_transients_of_simulated_sessions():
    """``tau_from_transients`` recovers the simulated lag of a one-round archive session
    (120 s dwells) from 2 s to 2 dwells, within 2 %."""
    from chekan.archive.synth import short_program
    from chekan.classical.settling import tau_from_transients
    from chekan.records.holds import segment_record
    from chekan.records.simulate import Truth, simulate_session

    for tau in (2.0, 5.0, 30.0, 240.0):
        rec, _ = simulate_session(short_program(), Truth(serial="T", tau_s=tau), seed=3)
        holds = segment_record(rec, settle_s=float(rec.meta["program_settle_s"]))
        assert abs(tau_from_transients(rec, holds) / tau - 1) < 0.02, tau
