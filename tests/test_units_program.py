import math

import pytest

from chekan.errors import ProgramError
from chekan.physics.program import build_program, default_program, load_program
from chekan.physics.units import (
    ARCSEC_PER_RAD,
    arcsec_to_rad,
    format_dms,
    one_minus_cos,
    parse_angle_deg,
    rad_to_arcmin,
)


@pytest.mark.parametrize(
    "text, deg",
    [
        ("5°10'", 5 + 10 / 60),
        ("5°10'00\"", 5 + 10 / 60),
        ("5°10′00″", 5 + 10 / 60),
        ("5d10m", 5 + 10 / 60),
        ("5d10m30s", 5 + 10 / 60 + 30 / 3600),
        ("-1°50'", -(1 + 50 / 60)),
        ("±1°50'", 1 + 50 / 60),
        ("5.1667", 5.1667),
        ("  2.5 ", 2.5),
        ("1e-3", 1e-3),
    ],
)
def test_parse_angle(text, deg):
    assert parse_angle_deg(text) == pytest.approx(deg, abs=1e-12)


@pytest.mark.parametrize("bad", ["", "abc", "5°70'", "5°10'70\"", "5 deg 10", "°10'"])
def test_parse_angle_rejects(bad):
    with pytest.raises(ValueError, match="not an angle"):
        parse_angle_deg(bad)


def test_format_round_trip():
    for d in (1 + 50 / 60, 5 + 10 / 60, 0.5):
        assert parse_angle_deg(format_dms(d)) == pytest.approx(d, abs=1 / 120)
        assert parse_angle_deg(format_dms(d, seconds=True)) == pytest.approx(d, abs=1e-9)
    assert format_dms(5 + 10 / 60, sign="pm") == "±5°10'"
    assert format_dms(-(1 + 50 / 60)) == "-1°50'"


def test_conversions():
    assert arcsec_to_rad(ARCSEC_PER_RAD) == pytest.approx(1.0)
    assert rad_to_arcmin(math.pi / 180) == pytest.approx(60.0)
    # 1 − cos θ without cancellation at 1″
    th = arcsec_to_rad(1.0)
    assert one_minus_cos(th) == pytest.approx(th * th / 2, rel=1e-12)


def test_default_program_is_the_papers():
    p = default_program()
    assert p.n_steps == 36 and p.duration_s == 9 * 3600
    labels = [s.label() for s in p.steps[:18]]
    assert labels[0] == "level" and labels[-1] == "level"
    assert labels[1:5] == ["+1°50'", "−1°50'", "+2°30'", "−2°30'"]
    assert labels[16] == "−5°10'"
    assert all(s.tilt_x_rad == 0 for s in p.steps)  # tilts about Y
    assert {s.round for s in p.steps} == {1, 2}
    assert all(s.settle_s == 300 and s.dwell_s == 900 for s in p.steps)


def test_program_from_toml(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text(
        'name = "mine"\nangles = ["1°", "2d30m", 4.5]\norder = "alternate"\n'
        "dwell_s = 600\nsettle_s = 200\nrounds = 2\n",
        encoding="utf-8",
    )
    p = load_program(f)
    assert p.name == "mine" and p.n_steps == 2 * (2 + 6)
    r2 = [s for s in p.steps if s.round == 2 and s.kind == "tilt"]
    assert r2[0].sign == -1  # alternate: −+ in even rounds
    assert p.steps[1].theta_rad == pytest.approx(math.radians(1.0))


@pytest.mark.parametrize(
    "body, msg",
    [
        ('angles = ["6°10\'"]', "beyond the 6° limit"),
        ("angles = []", "empty program"),
        ('angles = ["2°"]\ndwell_s = -5', "dwell_s must be positive"),
        ('angles = ["2°"]\ndwell_s = 100\nsettle_s = 200', "settle_s"),
        ('angles = ["two"]', "angles\\[0\\]"),
        ('angles = ["2°"]\nspeed = 3', "unknown key"),
        ("angles = [", "not valid TOML"),
    ],
)
def test_program_errors_name_the_file(tmp_path, body, msg):
    f = tmp_path / "bad.toml"
    f.write_text(body + "\n", encoding="utf-8")
    with pytest.raises(ProgramError, match=msg) as e:
        load_program(f)
    assert str(f) in str(e.value)


def test_build_program_validates():
    with pytest.raises(ProgramError, match="rounds"):
        build_program([1.0], rounds=0)
    with pytest.raises(ProgramError, match="axis"):
        build_program([1.0], axis="z")


def test_cli_program_shows_the_axis_of_every_round(tmp_path, capsys):
    from chekan.cli.commands import main

    f = tmp_path / "xy.toml"
    f.write_text('angles = ["2°", "4°"]\nround_axes = ["y", "x", "x"]\n', encoding="utf-8")
    assert main(["program", str(f)]) == 0
    out = capsys.readouterr().out
    assert "rounds Y, X, X" in out and "rounds: 1 about Y, 2 about X, 3 about X" in out
    rows = [ln for ln in out.splitlines() if "  round " in ln]
    assert len(rows) == 3 * 6
    assert all("about X" in r for r in rows if " round 3 " in r and "level" not in r)
    assert not any("about" in r for r in rows if "level" in r)


def test_round_axes_give_the_axis_of_each_round(tmp_path):
    f = tmp_path / "r.toml"
    f.write_text('angles = ["2°", "4°"]\nround_axes = ["x", "y", "x"]\n', encoding="utf-8")
    p = load_program(f)
    assert p.rounds == 3 and p.round_axes == ("x", "y", "x") and p.axis == "xy"
    for s in p.steps:
        assert s.axis == p.round_axes[s.round - 1]
        if s.kind == "tilt":
            about_x = s.axis == "x"
            assert (s.tilt_x_rad != 0.0) == about_x and (s.tilt_y_rad != 0.0) != about_x
    assert "rounds X, Y, X" in p.describe()
    # the same as axis = "xy" where that says it
    same = build_program([2.0, 4.0], round_axes=["y", "x", "y", "x"], rounds=4)
    assert same.steps == build_program([2.0, 4.0], axis="xy", rounds=4).steps
    assert build_program([2.0], round_axes=["x", "x"]).axis == "x"


def test_axis_programs_and_the_papers_are_unchanged():
    """Programs given by ``axis`` keep their steps; round_axes is filled from it."""
    p = default_program()
    assert p.round_axes == ("y", "y") and not p.axes_given and p.axis == "y"
    assert all(s.axis == "y" and s.tilt_x_rad == 0.0 for s in p.steps)
    assert "about Y," in p.describe()
    xy = build_program([2.0, 4.0], axis="xy", rounds=3)
    assert xy.round_axes == ("y", "x", "y") and "Y and X (alternate rounds)" in xy.describe()


@pytest.mark.parametrize(
    "body, msg",
    [
        ('round_axes = ["y", "x"]\nrounds = 3', "2 entries for 3 round"),
        ('round_axes = ["y", "z"]', "round_axes\\[1\\] must be 'y' or 'x'"),
        ('round_axes = "xy"', "must be a list"),
        ("round_axes = []", "0 entries for 2 round"),
        ('axis = "y"\nround_axes = ["y", "x"]', "either axis or round_axes"),
    ],
)
def test_round_axes_errors_name_the_file(tmp_path, body, msg):
    f = tmp_path / "bad.toml"
    f.write_text('angles = ["2°"]\n' + body + "\n", encoding="utf-8")
    with pytest.raises(ProgramError, match=msg) as e:
        load_program(f)
    assert str(f) in str(e.value)


def test_the_documented_program_files_are_the_programs_their_validations_name():
    """docs/figures holds the programs that the README's validations ran: each file loads,
    and its description is the one printed in the validation report beside it."""
    from pathlib import Path

    docs = Path(__file__).resolve().parents[1] / "docs" / "figures"
    report = (docs / "validation_dual_issue_programs.md").read_text(encoding="utf-8")
    for name, rounds, hours in (
        ("program_xy_6x4_540s", 6, 9.0),
        ("program_xy_3x20_188s", 20, 8.36),
    ):
        prog = load_program(docs / f"{name}.toml")
        assert prog.rounds == rounds and prog.round_axes[:2] == ("y", "x")
        assert prog.duration_s / 3600 == pytest.approx(hours, abs=0.005)
        assert f"| program | {prog.describe()} |" in report
        assert f"--program docs/figures/{name}.toml" in report
    assert load_program(docs / "program_design_xy.toml").tilt_axes == ("y", "x")
