"""Issue 33 §3–§4: impossible inputs are refused with one line and exit 2 (never numbers
with exit 0, never a traceback), and a fuzz of every numeric option of every command."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chekan.cli.commands import build_parser, main

RECORD_G = re.compile(r"^# g_local_mgal: .*$", re.M)


def run(argv: list[str], capsys) -> tuple[int, str]:
    """Exit status and standard error of ``chekan ARGV`` (argparse's usage errors too)."""
    try:
        status = main(argv)
    except SystemExit as e:  # argparse: a bad option value
        status = int(e.code or 0)
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return status, err


@pytest.fixture
def proto(tmp_path, paper_protocol) -> Path:
    p = tmp_path / "calibr_46.csv"
    p.write_bytes(Path(paper_protocol).read_bytes())
    return p


def _edited(src: Path, dst: Path, old: str, new: str, count: int = 1) -> Path:
    text = src.read_text(encoding="utf-8")
    assert old in text, old
    dst.write_text(text.replace(old, new, count), encoding="utf-8")
    return dst


# ------------------------------------------------------------------ §3 wrong numbers
@pytest.mark.parametrize("g", ["0", "-981922.05", "9.81", "981.92205", "1025340"])
def test_gravity_outside_the_earths_range_is_refused(g, short_session, proto, tmp_path, capsys):
    path, _, _ = short_session
    text = path.read_text(encoding="utf-8")
    line = text[: RECORD_G.search(text).start()].count("\n") + 1
    rec = tmp_path / "rec.csv"
    rec.write_text(RECORD_G.sub(f"# g_local_mgal: {g}", text, count=1), encoding="utf-8")
    status, err = run(["calibrate", str(rec), "-q"], capsys)
    assert status == 2 and f"{rec}:{line}: metadata g_local_mgal" in err, err
    assert "outside the Earth's gravity" in err and "mGal" in err
    p = _edited(proto, tmp_path / "p.csv", "# serial: 46", f"# serial: 46\n# g_local_mgal: {g}")
    status, err = run(["calibrate", str(p), "-q"], capsys)
    assert status == 2 and f"{p}:" in err and "outside the Earth's gravity" in err, err


def test_a_protocol_with_one_angle_is_refused_not_passed(proto, tmp_path, capsys):
    lines = proto.read_text(encoding="utf-8").splitlines(keepends=True)
    header = next(i for i, s in enumerate(lines) if s.startswith("angle"))
    one = tmp_path / "one.csv"
    one.write_text("".join(lines[: header + 2]), encoding="utf-8")
    status, err = run(["calibrate", str(one), "-q", "-o", str(tmp_path / "r.json")], capsys)
    assert status == 2 and "too few angles" in err, err
    assert not (tmp_path / "r.json").exists()
    # a fixed a leaves one coefficient fewer, but one angle still leaves no residual
    status, err = run(["calibrate", str(one), "-q", "--a-fixed", "1e-4"], capsys)
    assert status == 2 and "too few angles" in err, err


def test_a_mistyped_angle_in_a_protocol_names_its_row(proto, tmp_path, capsys):
    text = proto.read_text(encoding="utf-8")
    row = next(s for s in text.splitlines() if s.startswith("5°10'"))
    line = text.splitlines().index(row) + 1
    bad = _edited(proto, tmp_path / "typo.csv", row, row.replace("5°10'", "5°01'"))
    status, err = run(["calibrate", str(bad), "-q"], capsys)
    assert status == 2, err
    assert f"{bad}:{line}: da_ref_mgal 3989.59 does not match" in err and "5°01'" in err, err


def test_a_protocol_scale_factor_of_zero_is_refused(proto, tmp_path, capsys):
    text = proto.read_text(encoding="utf-8")
    key = re.search(r"^# (b_r1_s1): (.*)$", text, re.M)
    line = text[: key.start()].count("\n") + 1
    bad = _edited(proto, tmp_path / "b0.csv", key.group(0), "# b_r1_s1: 0")
    status, err = run(["calibrate", str(bad), "-q"], capsys)
    assert status == 2 and f"{bad}:{line}: metadata b_r1_s1" in err and "positive" in err, err


@pytest.mark.parametrize("value", ["NaN", "null", "-6.98", "0", '"6.98"'])
def test_a_result_without_a_scale_factor_is_refused(value, proto, tmp_path, capsys):
    res = tmp_path / "r.json"
    assert main(["calibrate", str(proto), "-q", "-o", str(res)]) == 0
    text = res.read_text(encoding="utf-8")
    data = json.loads(text)
    mean = data["parameters"]["b1"]["mean"]
    res.write_text(text.replace(f'"mean": {json.dumps(mean)}', f'"mean": {value}', 1))
    status, err = run(["report", str(res), "-o", str(tmp_path / "c.html")], capsys)
    assert status == 2 and "parameters.b1.mean" in err, err
    status, err = run(["archive", "add", str(res), "--db", str(tmp_path / "a.sqlite")], capsys)
    assert status == 1 and "parameters.b1.mean" in err, err


@pytest.mark.parametrize(
    "option",
    [
        ["--a-fixed", "nan"],
        ["--a-fixed", "inf"],
        ["--settle-s", "-5"],
        ["--hdi-prob", "0"],
        ["--hdi-prob", "1"],
        ["--hdi-prob", "1.5"],
        ["--seed", "-1"],
        ["--angle-bound-arcsec", "nan"],
    ],
)
def test_impossible_calibrate_options_are_refused(option, proto, tmp_path, capsys):
    out = tmp_path / "r.json"
    status, err = run(["calibrate", str(proto), "-q", "-o", str(out), *option], capsys)
    assert status == 2 and option[0] in err, err
    assert not out.exists()


# ------------------------------------------------------------------ §4 tracebacks
def test_an_impossible_reading_names_its_line(short_session, tmp_path, capsys):
    path, _, _ = short_session
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    header = next(i for i, s in enumerate(lines) if not s.startswith("#"))
    cols = lines[header].strip().split(",")
    i = header + 50
    fields = lines[i].rstrip("\n").split(",")
    fields[cols.index("m1_pix")] = "1e308"
    lines[i] = ",".join(fields) + "\n"
    rec = tmp_path / "huge.csv"
    rec.write_text("".join(lines), encoding="utf-8")
    status, err = run(["calibrate", str(rec), "-q", "--method", "map"], capsys)
    assert status == 2 and f"{rec}:{i + 1}: field m1_pix: 1e+308" in err, err


@pytest.mark.parametrize("method", ["classical", "map"])
def test_a_record_without_one_system_is_refused(method, short_session, tmp_path, capsys):
    path, _, _ = short_session
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    header = next(i for i, s in enumerate(lines) if not s.startswith("#"))
    j = lines[header].strip().split(",").index("m1_pix")
    for i in range(header + 1, len(lines)):
        fields = lines[i].rstrip("\n").split(",")
        fields[j] = ""
        lines[i] = ",".join(fields) + "\n"
    rec = tmp_path / "no_m1.csv"
    rec.write_text("".join(lines), encoding="utf-8")
    status, err = run(["calibrate", str(rec), "-q", "--method", method], capsys)
    assert status == 2 and f"{rec}: system 1 has no complete ± pair" in err, err


def test_history_refuses_a_plot_format_before_the_work(tmp_path, capsys):
    from chekan.archive.db import Archive

    Archive(tmp_path / "a.sqlite").close()
    status, err = run(
        ["history", "46", "--db", str(tmp_path / "a.sqlite"), "--plot", str(tmp_path / "x.txt")],
        capsys,
    )
    assert status == 2 and "x.txt" in err and ".png" in err, err


def test_calibrate_refuses_a_report_format_before_the_work(proto, tmp_path, capsys):
    out = tmp_path / "r.json"
    status, err = run(
        ["calibrate", str(proto), "-q", "-o", str(out), "--report", str(tmp_path / "c.txt")],
        capsys,
    )
    assert status == 2 and "c.txt" in err and not out.exists(), err


# ------------------------------------------------------------------ fuzz of the options
def _numeric_options() -> list[tuple[str, str]]:
    """(command path, option) of every option whose value is a number, from the parser."""
    found = []

    def walk(prefix: str, parser: argparse.ArgumentParser) -> None:
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    walk(f"{prefix} {name}".strip(), sub)
            elif a.type is not None and a.type is not str and a.option_strings:
                found.append((prefix, a.option_strings[-1]))

    walk("", build_parser())
    return found


NUMERIC = _numeric_options()
VALUES = st.one_of(
    st.sampled_from(
        [
            *("nan", "NaN", "inf", "-inf", "-1", "0", "-0", "1e308", "-1e308", "1e-300"),
            *("0.5", "1.5", "2", "65536", "9" * 30, "abc", "", "1_0", "0x10"),
        ]
    ),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
)


def test_every_numeric_option_is_fuzzed():
    names = {f"{c} {o}" for c, o in NUMERIC}
    assert {"calibrate --hdi-prob", "calibrate --a-fixed", "history --tolerance-ppm"} <= names
    assert {"emulate --speed", "acquire --give-up-s", "reanalyze --jobs"} <= names


@pytest.fixture(scope="module")
def fuzz_inputs(tmp_path_factory, paper_protocol) -> dict[str, Path]:
    from chekan.archive.db import Archive

    d = tmp_path_factory.mktemp("fuzz")
    prog = d / "tiny.toml"
    prog.write_text(
        'name = "tiny"\nangles = ["2°30\'", "4°10\'", "5°10\'"]\n'
        "dwell_s = 60\nsettle_s = 20\nrounds = 1\n",
        encoding="utf-8",
    )
    res = d / "r.json"
    assert main(["calibrate", str(paper_protocol), "-q", "-o", str(res)]) == 0
    Archive(d / "a.sqlite").close()
    (d / "empty").mkdir()
    return {"dir": d, "program": prog, "result": res, "protocol": Path(paper_protocol)}


def _argv(command: str, f: dict[str, Path], out: Path) -> list[str]:
    db = str(f["dir"] / "a.sqlite")
    return {
        "simulate": ["simulate", "--out", str(out / "s.csv"), "--program", str(f["program"])],
        "calibrate": ["calibrate", str(f["protocol"]), "-q", "-o", str(out / "r.json")],
        "design": ["design", str(f["program"])],
        "emulate": ["emulate", "--duration-s", "0"],
        "acquire": ["acquire", "-o", str(out / "a.csv"), "--sensor", "x", "--platform", "y"],
        "report": ["report", str(f["result"]), "-o", str(out / "c.html")],
        "live": ["live", str(f["protocol"])],
        "archive show": ["archive", "show", "1", "--db", db],
        "reanalyze": ["reanalyze", str(f["dir"] / "empty"), "--db", db, "-q"],
        "history": ["history", "46", "--db", db],
    }[command]


@pytest.mark.filterwarnings("error::RuntimeWarning")  # overflow: numbers that mean nothing
@pytest.mark.filterwarnings("error::scipy.linalg.LinAlgWarning")
@pytest.mark.parametrize("command,option", NUMERIC, ids=[f"{c} {o}" for c, o in NUMERIC])
@settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))
@given(value=VALUES)
def test_fuzz_numeric_options(command, option, value, fuzz_inputs, monkeypatch, capsys, tmp_path):
    """Exit 0 or 2 (3 for a calibration that --strict would flag: none here) and no traceback
    for any value of any numeric option; long-running commands stop after parsing."""
    import chekan.live as live
    import hw.cli as hwcli

    parsed = []

    def parsed_only(args):  # emulate, acquire, live run for hours: their parse is fuzzed
        parsed.append(args)
        return 0

    monkeypatch.setattr(hwcli, "cmd_emulate", parsed_only)
    monkeypatch.setattr(hwcli, "cmd_acquire", parsed_only)
    monkeypatch.setattr(live, "cmd_live", parsed_only)
    out = tmp_path / f"o{abs(hash(value))}"
    out.mkdir(exist_ok=True)
    argv = _argv(command, fuzz_inputs, out)
    if option in argv:  # the base command already names it: the fuzzed value replaces it
        i = argv.index(option)
        argv = argv[:i] + argv[i + 2 :]
    if command == "archive show":
        argv[2] = value
    else:
        argv += [f"{option}={value}"]
    status, err = run(argv, capsys)
    assert status in (0, 1, 2, 4), (argv, status, err)
    assert status != 1 or command == "reanalyze", (argv, err)
    if status == 2:  # one line that says what is wrong
        assert len(err.strip().splitlines()) == 1, err


def test_a_record_tilted_about_x_alone(tmp_path, capsys):
    """Rounds about X alone: the joint model calibrates them (issue 30, the X sensor's
    systematic line in the budget); the classical method fits them but flags the result
    (its g(1 − cos θ) describes tilts about Y), so --strict exits 3."""
    prog = tmp_path / "x.toml"
    prog.write_text(
        'name = "x"\nangles = ["2°30\'", "4°10\'", "5°10\'"]\naxis = "x"\n'
        "dwell_s = 300\nsettle_s = 100\nrounds = 3\n",  # 24 holds: the 2.6 h xy program's bucket
        encoding="utf-8",
    )
    rec = tmp_path / "rx.csv"
    assert main(["simulate", "--out", str(rec), "--program", str(prog)]) == 0
    capsys.readouterr()
    out = tmp_path / "rx.json"
    status, err = run(["calibrate", str(rec), "-q", "--method", "map", "-o", str(out)], capsys)
    assert status == 0, err
    res = json.loads(out.read_text())
    assert res["angle_sensor"]["axis"] == "x"
    assert res["uncertainty_budget"]["b1"]["angle_systematic"] > 0
    assert abs(res["parameters"]["b1"]["mean"] - 6.98) < 4 * res["parameters"]["b1"]["sd"]
    status, err = run(["calibrate", str(rec), "-q", "--method", "classical", "--strict"], capsys)
    assert status == 3 and not err.strip(), err
