"""The classical (Calibr.exe) method: the paper's numbers, simulated truth, the CLI."""

import json

import numpy as np
import pytest

from chekan.classical import calibrate_protocol, calibrate_record
from chekan.cli import main
from chekan.protocol import read_protocol
from chekan.result import read_result

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
    from chekan.simulate import Truth, simulate_session

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
