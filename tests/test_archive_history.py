"""The scale-history model: closed form against a dense NumPy reference, ML-II, alarms."""

from __future__ import annotations

import datetime as dt
import itertools

import numpy as np
import pytest

from chekan.archive.history import (
    Point,
    fit_history,
    param_history,
    select_points,
)


def dense_reference(tau, y, s, q, v, tq, kappa=1e10):
    """GP posterior with an explicit broad prior β ~ N(0, κI): joint Gaussian, conditioned."""
    H = np.stack([np.ones_like(tau), tau], 1)
    Hq = np.stack([np.ones_like(tq), tq], 1)
    K = q * np.minimum.outer(tau, tau) + kappa * H @ H.T
    Sy = K + np.diag(s**2 + v)
    Kq = q * np.minimum.outer(tq, tau) + kappa * Hq @ H.T
    Kqq = q * np.minimum.outer(tq, tq) + kappa * Hq @ Hq.T
    mean = Kq @ np.linalg.solve(Sy, y)
    cov = Kqq - Kq @ np.linalg.solve(Sy, Kq.T)
    # the slope r: covariance of β with y is κHᵀ
    r_mean = (kappa * H.T @ np.linalg.solve(Sy, y))[1]
    r_var = kappa - kappa**2 * (H.T @ np.linalg.solve(Sy, H))[1, 1]
    return mean, np.sqrt(np.diag(cov)), r_mean, np.sqrt(r_var)


def test_closed_form_matches_dense_gaussian_conditioning():
    rng = np.random.default_rng(3)
    tau = np.sort(rng.uniform(0, 9, 11))
    tau[0] = 0.0
    s = rng.uniform(30, 90, 11)
    y = 40 * tau + rng.normal(0, 1, 11) * s
    q, sx = 250.0, 20.0
    fit = fit_history(tau, y, s, q=q, sigma_x=sx)
    tq = np.array([0.0, 2.5, 8.0, 12.0, 15.0])
    m, sd = fit.predict(tq)
    m_ref, sd_ref, r_ref, r_sd_ref = dense_reference(tau, y, s, q, sx**2, tq)
    np.testing.assert_allclose(m, m_ref, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(sd, sd_ref, rtol=1e-5)
    r, r_sd = fit.rate
    assert r == pytest.approx(r_ref, rel=1e-6) and r_sd == pytest.approx(r_sd_ref, rel=1e-5)
    # no random walk, no extra error: weighted least squares of a straight line
    fit0 = fit_history(tau, y, s, q=0.0, sigma_x=0.0)
    W = np.diag(1 / s**2)
    H = np.stack([np.ones_like(tau), tau], 1)
    cov = np.linalg.inv(H.T @ W @ H)
    np.testing.assert_allclose(fit0.beta, cov @ H.T @ W @ y, rtol=1e-9)
    np.testing.assert_allclose(fit0.beta_cov, cov, rtol=1e-9)


def test_marginal_likelihood_recovers_random_walk_and_trend():
    rng = np.random.default_rng(7)
    n, q, s = 40, 400.0, 15.0  # 20 ppm/√yr random walk, 15 ppm sessions
    tau = np.sort(rng.uniform(0, 20, n))
    tau -= tau[0]
    w = np.concatenate([[0.0], np.cumsum(rng.normal(0, 1, n - 1) * np.sqrt(q * np.diff(tau)))])
    y = 5.0 + 30.0 * tau + w + rng.normal(0, s, n)
    fit = fit_history(tau, y, np.full(n, s))
    assert q / 4 < fit.q < 4 * q
    assert fit.sigma_x < 2 * s
    r, r_sd = fit.rate
    assert abs(r - 30.0) < 3 * r_sd
    # the prediction interval widens with the random walk beyond the last session
    _, sd = fit.predict(np.array([tau[-1], tau[-1] + 5.0]))
    assert sd[1] > sd[0] + 0.5 * np.sqrt(q * 5.0)


def points(values, sds, start=2010):
    return [
        Point(i + 1, f"{start + i}-06-01", "classical", v, s, None, None, f"r{i}.csv")
        for i, (v, s) in enumerate(zip(values, sds, strict=True))
    ]


def test_changes_z_and_alarms():
    b = 6.98
    vals = [b, b * (1 + 100e-6), b * (1 + 2600e-6), b * (1 + 2700e-6), b * (1 + 2650e-6)]
    pts = points(vals, [b * 100e-6] * 5)
    h, _ = param_history("b1", pts, "mGal/pix", at=dt.date(2015, 6, 1), tolerance_ppm=1000.0)
    dz = [c["z"] for c in h.changes]
    assert dz[1] == pytest.approx(2500e-6 * b / (np.sqrt(2) * b * 100e-6), rel=1e-2)
    kinds = [(a["level"], a["kind"], a["from"]) for a in h.alarms if a["kind"] == "change"]
    assert kinds == [("ALARM", "change", "2011-06-01")]
    assert "exceeds ±1000 ppm" in h.alarms[0]["message"]
    # 'a' is no scale factor: the ppm tolerance does not apply
    ha, _ = param_history("a", pts, "mGal/pix^2", at=dt.date(2015, 6, 1), tolerance_ppm=1000.0)
    assert ha.alarms == [] and len(ha.changes) == 4


def test_prediction_alarm_and_warning():
    b = 7.0
    rate = 200e-6  # per year, steady; sessions ±100 ppm
    pts = points([b * (1 + rate * i) for i in range(6)], [b * 100e-6] * 6)
    kw = dict(tolerance_ppm=500.0, extra_error=False)

    def at(date):
        return param_history("b2", pts, "mGal/pix", at=dt.date.fromisoformat(date), **kw)[0]

    h = at("2016-06-01")  # one year on: +200 ppm, the interval inside ±500 ppm
    assert h.alarms == []
    assert h.prediction["from_last_ppm"] == pytest.approx(200, abs=5)
    assert h.trend["ppm_per_year"] == pytest.approx(200 * b / h.reference, rel=1e-3)
    h = at("2017-06-01")  # +400 ppm: the mean inside, the 95 % interval not
    assert [(a["level"], a["kind"]) for a in h.alarms] == [("WARNING", "prediction")]
    assert h.prediction["high"] > pts[-1].mean * (1 + 500e-6) > h.prediction["mean"]
    h = at("2020-06-01")  # +1000 ppm
    assert [(a["level"], a["kind"]) for a in h.alarms] == [("ALARM", "prediction")]
    assert h.prediction["low"] < h.prediction["mean"] < h.prediction["high"]


def test_single_session_and_selection():
    h, fit = param_history(
        "b1", points([6.9], [0.001]), "mGal/pix", at=dt.date(2030, 1, 1), tolerance_ppm=100.0
    )
    assert fit is None and h.trend is None and h.prediction["mean"] == 6.9
    rows = []
    for sid, (method, ver) in enumerate(
        [("classical", "0.1"), ("map", "0.1"), ("bayes", "0.1"), ("bayes", "0.2")], start=1
    ):
        rows.append(
            dict(
                session_id=sid,
                input_sha256="x",
                method=method,
                calibrated_on="2012-01-01",
                parameter="b1",
                mean=float(sid),
                sd=0.1,
                hdi_low=None,
                hdi_high=None,
                input_path="p",
                software_version=ver,
            )
        )
    rows.append({**rows[0], "parameter": "a", "sd": None})  # held fixed in session 1
    pts, notes = select_points(rows, ("b1", "a"))
    assert [p.session_id for p in pts["b1"]] == [4]  # bayes, latest version
    pts, notes = select_points(rows, ("b1", "a"), method="classical")
    assert [p.session_id for p in pts["b1"]] == [1] and pts["a"] == []
    assert any("no uncertainty" in n for n in notes)


# ---------------------------------------------------------------- the decision rule (§7.8.6)
def test_decision_rule_is_guarded():
    from chekan.archive.history import decide

    assert decide(600.0, 50.0, 500.0, interval=False) == "ALARM"  # beyond by more than U
    assert decide(600.0, 200.0, 500.0, interval=False) == "WARNING"  # beyond, within U
    assert decide(450.0, 200.0, 500.0, interval=False) is None  # a change inside T
    assert decide(450.0, 200.0, 500.0, interval=True) == "WARNING"  # a prediction's interval


def test_no_alarm_for_changes_that_are_not_significant():
    """A stable instrument measured with 400 ppm sds: changes of several hundred ppm between
    verifications are noise, and no ALARM may fire on them (they fired on |Δ| > T alone)."""
    b = 6.98
    rng = np.random.default_rng(5)
    vals = b * (1 + 400e-6 * rng.standard_normal(40))
    pts = points(list(vals), [b * 400e-6] * 40, start=1980)
    h, _ = param_history("b1", pts, "mGal/pix", at=dt.date(2020, 1, 1), tolerance_ppm=500.0)
    beyond = [c for c in h.changes if abs(c["delta_ppm"]) > 500.0]
    assert beyond  # the old rule's alarms
    assert [a for a in h.alarms if a["level"] == "ALARM"] == []
    assert {a["level"] for a in h.alarms if a["kind"] == "change"} == {"WARNING"}
    assert all("inconclusive" in a["message"] for a in h.alarms if a["kind"] == "change")


def test_prediction_interval_grows_with_the_distance_in_time():
    b = 7.0
    pts = points([b * (1 + 50e-6 * (-1) ** i) for i in range(5)], [b * 100e-6] * 5)
    sds = [
        param_history("b1", pts, "mGal/pix", at=dt.date(y, 6, 1), tolerance_ppm=None)[0].prediction[
            "sd"
        ]
        for y in (2014, 2016, 2020, 2025)
    ]
    assert all(a < b_ for a, b_ in itertools.pairwise(sds)), sds
    assert sds[-1] > 2 * sds[0]
    # one date: the value, with no known uncertainty beyond it, and no alarm on it
    h, _ = param_history(
        "b1", points([6.9], [0.001]), "mGal/pix", at=dt.date(2021, 1, 1), tolerance_ppm=100.0
    )
    assert h.prediction["mean"] == 6.9 and h.prediction["sd"] == np.inf and h.alarms == []
    h, _ = param_history(
        "b1", points([6.9], [0.001]), "mGal/pix", at=dt.date(2010, 6, 1), tolerance_ppm=100.0
    )
    assert h.prediction["sd"] == 0.001  # at the session's own date: its own sd


def test_the_decision_rule_is_stated(tmp_path, paper_protocol):
    import copy

    from chekan.archive.db import Archive
    from chekan.archive.history import DECISION_RULE, format_history, stability_history
    from chekan.pipeline import CalibrationOptions, calibrate_file

    res = calibrate_file(paper_protocol, CalibrationOptions(method="classical", progress=False))
    with Archive(tmp_path / "a.sqlite") as a:
        for i, date in enumerate(("2015-07-09", "2016-07-09")):
            r = copy.deepcopy(res)
            r["record_sha256"], r["date"] = str(i) * 64, date
            a.add_result(r)
        hist = stability_history(a, "46", at="2017-01-01", tolerance_ppm=500.0)
    assert hist["decision_rule"] == DECISION_RULE
    assert f"decision rule: {DECISION_RULE}" in format_history(hist)


def test_plot_legend_names_each_panels_parameter():
    """The posterior's legend names the panel's parameter: "posterior of a(t)" on the a
    panel (it said "posterior of b(t)" on every panel)."""
    from dataclasses import asdict

    from chekan.archive.history import history_figure

    at = dt.date(2016, 1, 1)
    hist = {"serial": "T", "at": at.isoformat(), "hdi_prob": 0.95, "parameters": {}, "fits": {}}
    for name, unit, value in (("b1", "mGal/pix", 6.98), ("a", "mGal/pix^2", -7.8e-5)):
        pts = points([value * (1 + 1e-4 * i) for i in range(4)], [abs(value) * 1e-4] * 4)
        h, fit = param_history(name, pts, unit, at=at, tolerance_ppm=None)
        hist["parameters"][name] = asdict(h)
        hist["fits"][name] = fit
    fig = history_figure(hist)
    labels = [[t.get_text() for t in ax.get_legend().get_texts()] for ax in fig.axes]
    assert "posterior of b1(t)" in labels[0] and "posterior of a(t)" in labels[1], labels
    assert not any("b(t)" in x for x in labels[1]), labels


@pytest.mark.parametrize(
    "value,problem", [("2027-13-45", "month must be in 1..12"), ("banana", "YYYY-MM-DD")]
)
def test_at_is_a_date(tmp_path, capsys, value, problem):
    """An impossible date is one line naming the option and the problem, exit 2 (it was a
    ValueError's traceback, exit 1)."""
    from chekan.archive.db import Archive
    from chekan.cli.commands import main

    Archive(tmp_path / "a.sqlite").close()
    try:
        status = main(["history", "46", "--db", str(tmp_path / "a.sqlite"), "--at", value])
    except SystemExit as e:  # argparse's refusal of an option's value
        status = int(e.code or 0)
    err = capsys.readouterr().err
    assert status == 2 and len(err.strip().splitlines()) == 1, err
    assert "argument --at" in err and repr(value) in err and problem in err, err
