"""The classical (Calibr.exe) method: the paper's numbers, simulated truth, the CLI."""

import json

import numpy as np
import pytest

from chekan.classical.fit import (
    calibrate_protocol,
    calibrate_record,
    fit_by_axis,
    increments_from_holds,
)
from chekan.cli.commands import main
from chekan.records.protocol import read_protocol
from chekan.results.document import read_result

# Fig. 6 of the paper: δg per angle (rows) for r1_s1, r1_s2, r2_s1, r2_s2, and their mean Δg
PAPER_DELTA_G = np.array(
    [
        [-1.42, -1.01, -0.43, -0.95],
        [-0.49, 0.06, -0.27, -0.55],
        [-0.55, 0.21, -0.03, 0.49],
        [-0.39, 0.19, 0.34, 0.36],
        [0.47, 1.23, 0.23, 0.74],
        [-0.11, 0.27, -1.07, -0.65],
        [-0.31, -0.00, 0.88, 1.01],
        [0.75, -1.07, -0.14, -0.98],
    ]
)
PAPER_MEAN = np.array([-0.95, -0.31, 0.03, 0.12, 0.67, -0.39, 0.39, -0.36])
PAPER_B = np.array([[6.980343, 6.882650], [6.984589, 6.881965]])


def test_reproduces_the_paper_protocol(paper_protocol):
    res = calibrate_protocol(read_protocol(paper_protocol))
    dg = res.delta_g_mgal.reshape(4, 8).T  # (angle, column r1_s1 r1_s2 r2_s1 r2_s2)
    # the table is printed to 0.01 mGal from unrounded values: agree to one unit in the last digit
    np.testing.assert_allclose(dg, PAPER_DELTA_G, atol=0.0151)
    np.testing.assert_allclose(res.mean_delta_g_mgal, PAPER_MEAN, atol=0.0151)
    np.testing.assert_allclose(np.round(res.rms_mgal.ravel(), 2), [0.62, 0.69, 0.54, 0.75])
    assert round(res.reduced_error_percent, 3) == 0.019
    np.testing.assert_allclose(res.b, PAPER_B, rtol=1e-6)
    assert res.mean_all == pytest.approx(6.932387, rel=1e-6)  # «Среднее»
    assert round(res.discrepancy_percent, 3) == 0.035  # «Расхождение между приемами»
    assert res.a == pytest.approx(-7.828e-5)  # the protocol's a, mapped to the record convention
    assert res.a_sd is None


def test_recovers_simulated_truth(short_session):
    _, rec, truth = short_session
    res, holds = calibrate_record(rec, settle_s=200)
    assert holds.n == 36 and len(holds.rounds) == 2 and holds.angle_deg.size == 8
    for j in range(2):
        err = res.b_mean[j] - truth.b_mgal_per_pix[j]
        assert abs(err) < 5 * res.b_mean_sd[j] + 1e-3
    np.testing.assert_allclose(res.eps_arcmin, truth.eps_arcmin, atol=0.1)  # eq. (17)
    assert 0.1 < res.rms_mgal.mean() < 1.5
    b0 = res.b0(1024.0)
    assert b0.shape == (2, 2)
    rm = res.range_margin_gal((0, 2048))
    assert 5 < rm["heavy"] < 9 and 5 < rm["light"] < 9


def test_simulator_residuals_look_like_the_papers(short_program):
    """Default noise: classical СКП of the order of the paper's 0.5–1 mGal per column."""
    from chekan.records.simulate import Truth, simulate_session

    rms = []
    for seed in range(4):
        rec, _ = simulate_session(short_program, Truth(), seed=seed)
        res, _ = calibrate_record(rec, settle_s=200)
        rms.append(res.rms_mgal.mean())
    assert 0.3 < np.mean(rms) < 1.1


def test_a_fixed_and_fitted(short_session):
    _, rec, truth = short_session
    fitted, _ = calibrate_record(rec, settle_s=200)
    a_true = truth.derived()["a"]
    assert abs(fitted.a - a_true) < 5 * fitted.a_sd
    fixed, _ = calibrate_record(rec, settle_s=120, a_fixed=a_true)
    assert fixed.a == a_true and fixed.a_sd is None


def test_cli_calibrate_protocol_json(paper_protocol, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert (
        main(["calibrate", str(paper_protocol), "--method", "classical", "--json", str(out)]) == 0
    )
    text = capsys.readouterr().out
    assert "6.980339" in text and "0.019 %" in text and "СКП" in text
    res = read_result(out)
    assert res["format"] == "chekan-result/1" and res["method"] == "classical"
    assert res["serial"] == "46" and res["input_kind"] == "protocol"
    p = res["parameters"]
    assert p["b1"]["mean"] == pytest.approx(np.mean(PAPER_B[:, 0]), rel=1e-6)
    assert p["b1"]["hdi_low"] < p["b1"]["mean"] < p["b1"]["hdi_high"]
    assert "a" not in p and res["fixed"]["a"] == pytest.approx(-7.828e-5)  # not estimated
    assert res["reduced_error_percent"] == pytest.approx(0.019, abs=5e-4)
    assert res["mean_b_mgal_per_pix"] == pytest.approx(6.932387, rel=1e-6)
    assert len(res["record_sha256"]) == 64
    rs = res["residuals_mgal"]
    assert rs["columns"] == ["r1_s1", "r1_s2", "r2_s1", "r2_s2"]
    np.testing.assert_allclose(rs["delta_g_mgal"]["r2_s2"], PAPER_DELTA_G[:, 3], atol=0.0151)


def test_cli_simulate_then_calibrate_record(tmp_path, short_program, capsys):
    prog = tmp_path / "p.toml"
    prog.write_text(
        'angles = ["1°50\'", "3°10\'", "5°10\'"]\ndwell_s = 400\nsettle_s = 250\nrounds = 2\n',
        encoding="utf-8",
    )
    rec = tmp_path / "rec.csv"
    truth = tmp_path / "truth.json"
    assert (
        main(
            [
                "simulate",
                "--out",
                str(rec),
                "--seed",
                "3",
                "--truth",
                str(truth),
                "--program",
                str(prog),
            ]
        )
        == 0
    )
    out = tmp_path / "r.json"
    assert main(["calibrate", str(rec), "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    t = json.loads(truth.read_text())["parameters"]
    assert res["input_kind"] == "record" and "level_reading_pix" in res
    for k in ("b1", "b2", "b1_0", "b2_0", "a", "eps1_arcmin"):
        assert k in res["parameters"]
    assert abs(res["parameters"]["b1"]["mean"] - t["b1"]) < 0.01
    assert set(res["range_margin_gal"]) == {"heavy", "light"}
    assert "instability_percent" in res  # the simulator writes b1_prior/b2_prior


def test_cli_errors_are_clear(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text(
        "# format: chekan-record/1\n# serial: 1\n# g_local_mgal: 9.8e5\n"
        "t_s,m1_pix,m2_pix,tilt_x_arcsec,tilt_y_arcsec,step\n0,1,2,3,4,0\n1,x,2,3,4,0\n"
        "2,1,2,3,4,0\n",
        encoding="utf-8",
    )
    assert main(["calibrate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:6:" in err and "m1_pix" in err


# ------------------------------------------------------------------ rounds about X (issue 30)

G_MGAL = 981922.05
K_PIX = 60428.0
B_TRUE = (6.98, 6.882)


def _forward_record(program, m_level=(1024.0, 1024.0), dt_s=10.0, serial="AX-1"):
    """A noise-free record of ``program`` from the forward model itself (eq. 6, ideal
    geometry: ε = γ = 0): every sample of a hold is the equilibrium reading there."""
    from chekan.physics import sensor as fm
    from chekan.physics.units import ARCSEC_PER_RAD
    from chekan.records import Record

    params = fm.make_params(
        g_mgal=G_MGAL, K_pix_per_rad=K_PIX, b_mgal_per_pix=B_TRUE, m_level_pix=m_level
    )
    n = [int(s.dwell_s / dt_s) for s in program.steps]
    tx = np.repeat([s.tilt_x_rad for s in program.steps], n)
    ty = np.repeat([s.tilt_y_rad for s in program.steps], n)
    m = np.asarray(fm.equilibrium_readings(params, tx, ty))
    rec = Record(
        meta={
            "format": "chekan-record/1",
            "serial": serial,
            "g_local_mgal": repr(G_MGAL),
            "program_settle_s": f"{program.settle_s:g}",
        },
        t_s=dt_s * np.arange(tx.size),
        m1_pix=m[:, 0],
        m2_pix=m[:, 1],
        tilt_x_arcsec=tx * ARCSEC_PER_RAD,
        tilt_y_arcsec=ty * ARCSEC_PER_RAD,
        step=np.repeat([s.index for s in program.steps], n),
    )
    return rec, params


def _xy_program(**kw):
    from chekan.physics.program import build_program

    kw = {"round_axes": ["y", "x", "y", "x"], "dwell_s": 200, "settle_s": 100, **kw}
    return build_program([1 + 50 / 60, 3 + 10 / 60, 4 + 10 / 60, 5 + 10 / 60], **kw)


def test_rounds_about_x_are_processed_per_axis_with_analytic_truth():
    """Y rounds give b to the quadratic model's truncation; X rounds are fitted apart: their
    ± pairs cancel the terms linear in θ (eq. 25), and their pair means are the Y rounds'
    times 1 + (gθ/λ)² (eq. 6: a tilt about X changes the stiffness by gθ), so their own a
    is ≈ 5a (λ = bK, a = g/2K²)."""
    from chekan.physics import sensor as fm

    rec, params = _forward_record(_xy_program())
    res, holds = calibrate_record(rec, settle_s=100)
    assert holds.axis == "xy" and [r.axis for r in holds.rounds] == ["y", "x", "y", "x"]
    assert res.axis == "y" and set(res.by_axis) == {"y", "x"} and res.by_axis["y"] is res
    assert res.table.rounds == (1, 3) and res.by_axis["x"].table.rounds == (2, 4)
    # the live page's preview goes the same way (fit_by_axis of the whole table)
    whole = increments_from_holds(holds, G_MGAL)
    assert whole.axes == ("y", "x", "y", "x")
    np.testing.assert_array_equal(fit_by_axis(whole, preview=True).b, res.b)
    # without the X rounds' own fit (the posterior predictive's δg table): the same table
    alone = fit_by_axis(whole, x_apart=False)
    assert "x" not in alone.by_axis
    np.testing.assert_array_equal(alone.delta_g_mgal, res.delta_g_mgal)
    assert alone.a == res.a
    np.testing.assert_allclose(res.b_mean, B_TRUE, rtol=1e-4)  # truncation: ≈ 2e-5
    a_true = float(np.mean(fm.quadratic_coefficient(params, params.m_level_pix)))
    assert res.a == pytest.approx(a_true, rel=0.02)
    xr = res.by_axis["x"]
    assert xr.axis == "x" and xr.eps_arcmin is None  # eq. (17) is about Y tilts
    np.testing.assert_allclose(xr.b_mean, B_TRUE, rtol=2e-3)
    assert 4.5 < xr.a / a_true < 5.2
    # pair means (eq. 25): X over Y = 1/(1 − u²), u = g sin θ/λ, λ = bK at m_h = m₀, to
    # leading order in the deflection (λδ = gΔu_z + g sin θ·δ); 6 % of the excess at 5°10′
    theta = xr.table.theta_pair_rad[0]
    lam = np.asarray(B_TRUE) * K_PIX
    ratio = xr.table.x_pix[0] / res.table.x_pix[0]  # (2, n)
    u = G_MGAL * np.sin(theta[None, :]) / lam[:, None]
    np.testing.assert_allclose(ratio - 1, u**2 / (1 - u**2), rtol=0.08)
    assert np.all(ratio - 1 > 0.005)  # far above the Y rounds' truncation (2e-5)


def test_cli_classical_on_both_axes_labelled_tables_no_warnings(tmp_path, capsys):
    """``chekan calibrate`` of a Y/X record: one table per axis, labelled, with only that
    axis's rounds and angles (no empty column, no ±0°00′ row, no "—"), no warning on the
    terminal; the JSON holds each axis's fit and the certificate's (Y) parameters."""
    import warnings

    from chekan.records import write_record

    rec, _ = _forward_record(_xy_program(round_axes=["y", "x", "x", "y"]))
    path, out = tmp_path / "xy.csv", tmp_path / "xy.json"
    write_record(path, rec)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["calibrate", str(path), "--method", "classical", "--json", str(out)]) == 0
    cap = capsys.readouterr()
    assert "Warning" not in cap.err and "warning" not in cap.out.lower()
    text = cap.out
    assert "rounds about Y (round(s) 1, 4; the certificate's)" in text
    assert "rounds about X (round(s) 2, 3; not certified)" in text
    tables = text.split("classical method per axis")[1]
    assert "—" not in tables and "0°00" not in tables
    y_part, x_part = text.split("rounds about X (round(s)")
    assert "dg r1_s1" in y_part and "dg r4_s2" in y_part and "r2_s1" not in y_part.split("Y (")[-1]
    assert "dg r2_s1" in x_part and "dg r3_s2" in x_part and "r1_s1" not in x_part
    res = json.loads(out.read_text())
    assert res["classical_axis"] == "y"
    by = res["classical_by_axis"]
    assert by["y"]["used_by_certificate"] and not by["x"]["used_by_certificate"]
    assert [r["round"] for r in by["x"]["rounds"]] == [2, 3]
    assert [r["axis"] for r in res["rounds"]] == ["y", "y"]
    assert res["parameters"]["b1"]["mean"] == by["y"]["parameters"]["b1"]["mean"]
    assert abs(res["parameters"]["b1"]["mean"] / B_TRUE[0] - 1) < 1e-4
    assert by["x"]["residuals_mgal"]["columns"] == ["r2_s1", "r2_s2", "r3_s1", "r3_s2"]
    assert len(by["x"]["residuals_mgal"]["angle_label"]) == 4


def test_x_rounds_alone_give_a_flagged_result(tmp_path, capsys):
    from chekan.physics.program import build_program
    from chekan.records import write_record

    prog = build_program([2.5, 4 + 10 / 60, 5 + 10 / 60], axis="x", dwell_s=200, settle_s=100)
    rec, _ = _forward_record(prog, m_level=(1031.2, 1012.9))
    path = tmp_path / "x.csv"
    write_record(path, rec)
    res, _ = calibrate_record(rec, settle_s=100)
    assert res.axis == "x" and res.problems and not res.by_axis
    assert main(["calibrate", str(path), "--method", "classical", "--settle-s", "100"]) == 0
    out = capsys.readouterr().out
    assert "WARNING: every round is about the platform X axis" in out
    argv = ["calibrate", str(path), "--method", "classical", "--settle-s", "100", "--strict"]
    assert main(argv) == 3


def test_each_axis_table_holds_only_its_own_angles():
    """X rounds at other angles than the Y rounds (another recorder's program): each axis's
    table has its own angles, no empty row or column."""
    import dataclasses
    from types import SimpleNamespace

    from chekan.physics.program import build_program

    y = build_program([2.0, 4.0], axis="y", dwell_s=200, settle_s=100, rounds=2)
    x = build_program([3.0, 5.0], axis="x", dwell_s=200, settle_s=100, rounds=1)
    steps = list(y.steps) + [
        dataclasses.replace(s, index=s.index + y.n_steps, round=s.round + 2) for s in x.steps
    ]
    rec, _ = _forward_record(SimpleNamespace(steps=steps, settle_s=100.0))
    res, holds = calibrate_record(rec, settle_s=100)
    assert holds.angle_deg.size == 4 and res.axis == "y"
    for fit, labels in ((res, ["±2°00'", "±4°00'"]), (res.by_axis["x"], ["±3°00'", "±5°00'"])):
        assert fit.table.angle_label == labels
        assert np.isfinite(fit.table.x_pix).all() and np.isfinite(fit.delta_g_mgal).all()
    assert res.by_axis["x"].table.rounds == (3,) and res.discrepancy_percent is not None


def test_replicated_readings_give_each_tables_own_increments():
    """The posterior predictive replicates a session many times with new hold means:
    :func:`increments_of_readings` computes them together and must give, for each, what
    :func:`increments_from_holds` gives the table holding those means (both axes, levels
    interpolated in time), bit for bit."""
    from dataclasses import replace

    from chekan.classical.fit import increments_of_readings

    rec, _ = _forward_record(_xy_program())
    _, holds = calibrate_record(rec, settle_s=100)
    rng = np.random.default_rng(3)
    readings = holds.m_mean_pix[None] + rng.normal(0, 0.5, (3, *holds.m_mean_pix.shape))
    tables = increments_of_readings(holds, G_MGAL, readings)
    assert len(tables) == 3
    for y, got in zip(readings, tables, strict=True):
        want = increments_from_holds(replace(holds, m_mean_pix=y), G_MGAL)
        for name in ("x_pix", "x_plus_pix", "x_minus_pix", "m_level_pix", "da_ref_mgal"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        assert got.axes == want.axes and got.notes == want.notes
    assert not np.array_equal(tables[0].x_pix, tables[1].x_pix)  # the readings did enter
