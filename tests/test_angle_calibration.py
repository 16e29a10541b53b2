"""The platform's own angle calibration (chekan.records.anglecal, issue 29): the file format and
its errors, the corrections applied to the measured angles, its uncertainty replacing the
bound's prior (the sd of b falls as the budget says), the result and CLI naming it."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from chekan.cli.commands import main
from chekan.errors import ChekanError, FormatError
from chekan.options import CalibrationOptions
from chekan.pipeline import calibrate
from chekan.records import write_record
from chekan.records.anglecal import corrected, read_angle_calibration
from chekan.records.simulate import Truth, simulate_session
from chekan.study.scenario import session_calibration

HEAD = "# format: chekan-angle-calibration/1\n# id: AC-1\n# date: 2026-10-02\n"
COLS = "axis,angle_arcsec,correction_arcsec,U_arcsec\n"


def _write(tmp_path: Path, body: str, head: str = HEAD, name: str = "cal.csv") -> Path:
    p = tmp_path / name
    p.write_text(head + COLS + body)
    return p


def test_reads_a_table_and_interpolates_without_extrapolating(tmp_path):
    p = _write(tmp_path, "y,-1000,1.0,0.4\ny,1000,-1.0,0.8\ny,0,0.5,0.6\n")
    cal = read_angle_calibration(p)
    t = cal.table("y")
    assert t is not None and cal.table("x") is None
    np.testing.assert_array_equal(t.angle_arcsec, [-1000, 0, 1000])  # sorted
    np.testing.assert_allclose(t.correction_at(np.array([-500.0, 500.0])), [0.75, -0.25])
    np.testing.assert_allclose(t.u_at(np.array([500.0])), [0.35])  # U/2, interpolated
    assert t.covers(np.array([1029.0, -1029.0])).all()  # the end tolerance, 30″
    assert not t.covers(np.array([1031.0])).any()
    assert cal.entry()["id"] == "AC-1" and cal.entry()["date"] == "2026-10-02"
    assert len(cal.entry()["sha256"]) == 64


@pytest.mark.parametrize(
    ("body", "head", "where", "what"),
    [
        ("y,0,0.1,0.5\ny,100,0.2\n", HEAD, ":6:", "3 fields"),
        ("y,0,0.1,0.5\ny,100,0.2,-0.1\n", HEAD, ":6:", "U_arcsec must be ≥ 0"),
        ("y,0,0.1,0.5\ny,1e2x,0.2,0.1\n", HEAD, ":6:", "not a finite number"),
        ("y,0,0.1,0.5\ny,0,0.2,0.1\n", HEAD, ":6:", "given twice"),
        ("z,0,0.1,0.5\n", HEAD, ":5:", "expected x or y"),
        ("y,0,0.1,0.5\n", HEAD, ":5:", "at least two angles"),
        ("y,0,0.1,0.5\ny,9,0.1,0.5\n", HEAD.replace("2026-10-02", "2.10.2026"), ":3:", "date"),
        ("y,0,0.1,0.5\ny,9,0.1,0.5\n", HEAD.replace("# id: AC-1\n", ""), "", "'id'"),
    ],
)
def test_a_malformed_table_names_the_file_and_line(tmp_path, body, head, where, what):
    p = _write(tmp_path, body, head)
    with pytest.raises(FormatError) as e:
        read_angle_calibration(p)
    assert str(e.value).startswith(f"{p}{where}") and what in str(e.value)


@pytest.fixture(scope="module")
def session(short_program):
    """A short session whose sensor has a systematic error at its 3″ bound, small random
    errors, and the platform's calibration of it with residual U = 0.5″."""
    truth = Truth(
        serial="AC-T",
        angle_systematic_arcsec=3.0,
        angle_systematic_peak=(1.0, 1.0),
        angle_error_sd_arcsec=0.5,
    )
    rec, truth = simulate_session(short_program, truth, seed=11)
    cal = session_calibration(truth, short_program, 11, 0.5)
    return rec, truth, cal


def test_corrections_are_applied_to_the_measured_angles(session):
    rec, _truth, cal = session
    fixed = corrected(rec, cal)
    table = cal.table("y")
    np.testing.assert_allclose(
        fixed.tilt_y_arcsec, rec.tilt_y_arcsec + table.correction_at(rec.tilt_y_arcsec)
    )
    np.testing.assert_array_equal(fixed.tilt_x_arcsec, rec.tilt_x_arcsec)
    assert rec.angle_calibration is None  # what it was handed is unchanged
    assert fixed.angle_calibration is cal


def test_a_table_that_does_not_cover_the_program_is_an_error(session, tmp_path):
    rec, _truth, _cal = session
    p = _write(tmp_path, "y,-10000,0.1,0.5\ny,10000,0.1,0.5\n")
    with pytest.raises(ChekanError, match=r"cal\.csv: axis y covers -10000…10000″.*extrapolated"):
        corrected(rec, read_angle_calibration(p))


def test_the_sd_of_b_falls_as_the_budget_says_and_the_bound_platform_is_covered(session):
    """With the platform's calibration (U = 0.5″) only the systematic line of the budget
    shrinks: sd(b)² falls by the difference of that line's squares; the platform at its
    bound is covered with the bound (rectangular) and with the calibration."""
    rec, truth, cal = session
    opts = CalibrationOptions(method="map", progress=False)
    bound = calibrate(rec, opts)
    table = calibrate(rec, CalibrationOptions(method="map", progress=False, angle_calibration=cal))
    assert table["angle_sensor"]["calibration"]["id"] == cal.id
    assert table["angle_sensor"]["distribution"] == "normal"
    assert table["angle_calibration"]["id"] == cal.id
    assert bound["angle_sensor"]["distribution"] == "rectangular"
    for k, b_true in zip(("b1", "b2"), truth.b_mgal_per_pix, strict=True):
        sd0, sd1 = bound["parameters"][k]["sd"], table["parameters"][k]["sd"]
        sys0 = bound["uncertainty_budget"][k]["angle_systematic"]
        sys1 = table["uncertainty_budget"][k]["angle_systematic"]
        assert sys1 < 0.3 * sys0  # u 0.25″ against 1.73″
        # the Type A lines are re-estimated from the corrected angles (σ_o, σ_θ by EM):
        # the sd falls as the systematic line says, to within 15 %
        assert sd1**2 == pytest.approx(sd0**2 - sys0**2 + sys1**2, rel=0.15)
        assert sd1 < 0.8 * sd0
        for r in (bound, table):
            z = (r["parameters"][k]["mean"] - b_true) / r["parameters"][k]["sd"]
            assert abs(z) < 1.96, (k, z)


def test_cli_takes_the_table_from_the_option_or_the_header(session, tmp_path, capsys):
    rec, _truth, cal = session
    t = cal.table("y")  # the same table, on disk
    lines = [
        f"y,{a:.3f},{c:.5f},{u:g}"
        for a, c, u in zip(t.angle_arcsec, t.correction_arcsec, t.U_arcsec, strict=True)
    ]
    cal_path = _write(tmp_path, "\n".join(lines) + "\n")
    rec_path = tmp_path / "rec.csv"
    write_record(rec_path, rec)
    out = tmp_path / "r.json"
    assert (
        main(
            [
                "calibrate",
                str(rec_path),
                "--method",
                "map",
                "--angle-calibration",
                str(cal_path),
                "-q",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    r1 = json.loads(out.read_text())
    assert r1["angle_calibration"]["file"] == str(cal_path)
    # named in the record header, relative to the record's folder
    rec2 = tmp_path / "rec2.csv"
    write_record(rec2, dataclasses.replace(rec, meta={**rec.meta, "angle_calibration": "cal.csv"}))
    out2 = tmp_path / "r2.json"
    assert main(["calibrate", str(rec2), "--method", "map", "-q", "--json", str(out2)]) == 0
    r2 = json.loads(out2.read_text())
    assert r2["angle_calibration"]["sha256"] == r1["angle_calibration"]["sha256"]
    assert r2["parameters"]["b1"]["mean"] == pytest.approx(
        r1["parameters"]["b1"]["mean"], rel=1e-12
    )
    # a header naming a missing file, a table not covering: exit 2, one line naming the file
    missing = {**rec.meta, "angle_calibration": "missing.csv"}
    write_record(rec2, dataclasses.replace(rec, meta=missing))
    capsys.readouterr()
    assert main(["calibrate", str(rec2), "--method", "classical", "-q"]) == 2
    err = capsys.readouterr().err
    assert "missing.csv" in err and "Traceback" not in err
    narrow = _write(tmp_path, "y,-100,0,0.5\ny,100,0,0.5\n", name="narrow.csv")
    assert main(["calibrate", str(rec_path), "--angle-calibration", str(narrow), "-q"]) == 2
    assert "narrow.csv: axis y covers" in capsys.readouterr().err
    assert math.isfinite(r1["parameters"]["b1"]["sd"])


def test_the_certificate_states_the_reading_its_source_and_the_angle_calibration(session):
    from chekan.report.content import build_report

    rec, _truth, cal = session
    bound = calibrate(rec, CalibrationOptions(method="map", progress=False))
    table = calibrate(rec, CalibrationOptions(method="map", progress=False, angle_calibration=cal))
    text0 = repr(build_report(bound, lang="en", figures=False))
    assert "GUM 4.3.7" in text0 and "the paper's specification" in text0
    text1 = repr(build_report(table, lang="en", figures=False))
    assert f"{cal.id} of {cal.date}" in text1 and "angle calibration " + cal.id in text1
    assert "GUM 4.3.7" not in text1


SCALE_ROWS = "y,-1000,0.1,0.5\ny,0,0.0,0.4\ny,1000,-0.1,0.5\n"


def test_a_stated_scale_part_is_read_checked_and_replaces_the_extremes(tmp_path):
    """``scale_part_y_arcsec``: the part of U that is a scale error. The prior then gives the
    scale term u_s(θ_max)² and each angle u(θ)² − u_s(θ)², u_s(θ) = (U_s/2)·|θ|/θ_t, where
    a table alone gets both extremes at the full u²; the result and the reading state it."""
    from chekan.joint.angles import SystematicBasis, spec_for
    from chekan.physics.units import ARCSEC_PER_RAD
    from chekan.results.entries import angle_sensor_entry

    plain = read_angle_calibration(_write(tmp_path, SCALE_ROWS, name="plain.csv"))
    cal = read_angle_calibration(
        _write(tmp_path, SCALE_ROWS, HEAD + "# scale_part_y_arcsec: 0.3\n", name="stated.csv")
    )
    assert plain.table("y").scale_U_arcsec is None and "scale_U_arcsec" not in plain.entry()
    assert cal.table("y").scale_U_arcsec == 0.3 and cal.entry()["scale_U_arcsec"] == {"y": 0.3}
    nodes = np.array([-800.0, 0.0, 800.0]) / ARCSEC_PER_RAD  # commanded angles
    basis = SystematicBasis(nodes, 800.0 / ARCSEC_PER_RAD)
    u = np.array([0.24, 0.2, 0.24])  # U/2 interpolated at ∓800″ and 0″
    np.testing.assert_allclose(
        basis.prior_var(spec_for({}, None, calibration=plain)), [*u**2, 0.24**2]
    )
    us = 0.15 * np.array([0.8, 0.0, 0.8])  # (U_s/2)·|θ|/1000″
    stated = spec_for({}, None, calibration=cal)
    np.testing.assert_allclose(basis.prior_var(stated), [*(u**2 - us**2), 0.12**2])
    entry = angle_sensor_entry(stated)
    assert "scale error U = 0.3″ at 1000″" in entry["reading"] and "stated" in entry["reading"]
    assert entry["u_scale_arcsec"] == pytest.approx(0.15)
    assert entry["u_per_angle_arcsec"] == pytest.approx(0.2)  # the largest per-angle part


@pytest.mark.parametrize(
    ("key", "what"),
    [
        ("scale_part_x_arcsec: 0.1", "no x rows"),
        ("scale_part_y_arcsec: -0.1", "expected arcsec ≥ 0"),
        ("scale_part_y_arcsec: lots", "expected arcsec ≥ 0"),
        ("scale_part_y_arcsec: 0.6", "not a part of U: at -1000″ its share 0.6″ exceeds"),
    ],
)
def test_a_bad_scale_statement_names_the_file_and_line(tmp_path, key, what):
    p = _write(tmp_path, SCALE_ROWS, HEAD + f"# {key}\n")
    with pytest.raises(FormatError) as e:
        read_angle_calibration(p)
    assert str(e.value).startswith(f"{p}:4:") and what in str(e.value)


def test_the_simulated_lab_states_its_scale_part(session, short_program):
    """The validation's tables: stated as independent (0) they are the unstated tables to
    the bit; with a scale part U_s the residual is ξ·θ/θ_t plus the unstated draw's normals
    scaled to the rest, √(U² − (U_s·θ/θ_t)²)/2, so that each row's total stays U."""
    from chekan.physics.units import ARCSEC_PER_RAD
    from chekan.records.simulate import session_systematic

    _rec, truth, cal = session
    plain = cal.table("y")
    zero = session_calibration(truth, short_program, 11, 0.5, 0.0).table("y")
    np.testing.assert_array_equal(zero.correction_arcsec, plain.correction_arcsec)
    assert zero.scale_U_arcsec == 0.0 and plain.scale_U_arcsec is None
    whole = session_calibration(truth, short_program, 11, 0.5, 0.5).table("y")
    fn = session_systematic(truth, short_program, 11, "y")
    truth_at = -fn(whole.angle_arcsec / ARCSEC_PER_RAD)
    r, r0 = whole.correction_arcsec - truth_at, plain.correction_arcsec - truth_at
    t = whole.angle_arcsec / whole.max_angle_arcsec
    end = int(np.argmax(np.abs(t)))  # there the whole of U is the scale part
    xi = r[end] / t[end]
    own = np.sqrt(np.maximum(0.5**2 - (0.5 * t) ** 2, 0.0)) / 2
    np.testing.assert_allclose(r, r0 * own / 0.25 + xi * t, atol=1e-12)
    assert 0.0 < abs(xi) < 1.0 and whole.scale_U_arcsec == 0.5


def test_a_stated_scale_part_narrows_the_systematic_line(session):
    """Stated as independent (U_s = 0), the table's residual loses its scale extreme: the
    systematic line of b's budget falls, the rest of the calibration is unchanged, and the
    platform is still covered."""
    rec, truth, cal = session
    stated = dataclasses.replace(
        cal, tables={"y": dataclasses.replace(cal.table("y"), scale_U_arcsec=0.0)}
    )
    both, indep = (
        calibrate(rec, CalibrationOptions(method="map", progress=False, angle_calibration=c))
        for c in (cal, stated)
    )
    assert "stated" in indep["angle_sensor"]["reading"]
    assert indep["angle_calibration"]["scale_U_arcsec"] == {"y": 0.0}
    from chekan.report.content import build_report

    assert "which states its scale part" in repr(build_report(indep, lang="en", figures=False))
    assert "which states its scale part" not in repr(build_report(both, lang="en", figures=False))
    for k, b_true in zip(("b1", "b2"), truth.b_mgal_per_pix, strict=True):
        sys0 = both["uncertainty_budget"][k]["angle_systematic"]
        sys1 = indep["uncertainty_budget"][k]["angle_systematic"]
        assert sys1 < 0.9 * sys0
        assert indep["parameters"][k]["sd"] < both["parameters"][k]["sd"]
        z = (indep["parameters"][k]["mean"] - b_true) / indep["parameters"][k]["sd"]
        assert abs(z) < 1.96, (k, z)


def test_the_design_says_what_the_table_states(tmp_path):
    from chekan.design.command import angle_sensors_text
    from chekan.design.layout import DesignValues

    head = HEAD + "# scale_part_y_arcsec: 0.25\n"
    cal = read_angle_calibration(_write(tmp_path, SCALE_ROWS, head))
    text = angle_sensors_text(DesignValues(angle_calibration=cal))
    assert "Y: its table, U ≤ 0.5″ (k = 2), of it a scale error 0.25″ (stated)" in text
    plain = read_angle_calibration(_write(tmp_path, SCALE_ROWS, name="p.csv"))
    assert "stated" not in angle_sensors_text(DesignValues(angle_calibration=plain))
