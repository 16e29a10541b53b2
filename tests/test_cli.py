"""The command line as a user meets it: outputs that must not be written, closed pipes,
exit statuses, short options. Cheap: the paper's protocol and the classical method."""

from __future__ import annotations

import argparse
import os
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from chekan.cli.commands import EXIT_STATUS, build_parser, main
from chekan.files.durable import atomic_output
from chekan.files.outputs import OutputError, check_outputs, sniff_format

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = ROOT / "examples" / "calibr_46_protocol.csv"
RECORD_HEAD = "# format: chekan-record/1\n# serial: 46\n# g_local_mgal: 981922.05\nt_s,m1_pix\n"


@pytest.fixture
def proto(tmp_path) -> Path:
    p = tmp_path / "calibr_46.csv"
    p.write_bytes(PROTOCOL.read_bytes())
    return p


@pytest.fixture
def record(tmp_path) -> Path:
    """A file that begins like a record (the guard reads only the head)."""
    p = tmp_path / "measured.csv"
    p.write_text(RECORD_HEAD + "0,1.0\n", encoding="utf-8")
    return p


def _fail(capsys, argv: list[str], name: Path) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(name) in err and "refusing" in err
    return err


# ------------------------------------------------------------------ 1. data loss
def test_calibrate_refuses_to_write_its_result_over_its_input(proto, capsys):
    before = proto.read_bytes()
    _fail(capsys, ["calibrate", str(proto), "--method", "classical", "--json", str(proto)], proto)
    assert proto.read_bytes() == before
    # the same file by another name: through '..' and through a symbolic link
    other = proto.parent / "sub" / ".." / proto.name
    (proto.parent / "sub").mkdir()
    _fail(capsys, ["calibrate", str(proto), "-q", "-o", str(other)], other)
    link = proto.parent / "link.json"
    link.symlink_to(proto)
    _fail(capsys, ["calibrate", str(proto), "-q", "-o", str(link)], link)
    assert proto.read_bytes() == before


def test_no_output_option_overwrites_a_record_or_protocol(proto, record, tmp_path, capsys):
    rec_before = record.read_bytes()
    ok = tmp_path / "ok.json"
    # refused before the work: the result JSON given beside the refused report is not written
    _fail(capsys, ["calibrate", str(proto), "-q", "-o", str(ok), "--report", str(record)], record)
    assert not ok.exists()
    _fail(capsys, ["simulate", "--out", str(record)], record)
    _fail(capsys, ["design", "--json", str(proto)], proto)
    _fail(capsys, ["design", "-o", str(record)], record)
    db = str(tmp_path / "a.sqlite")
    _fail(capsys, ["archive", "export", str(record), "--db", db], record)
    _fail(capsys, ["archive", "export", "-o", str(proto), "--db", db], proto)
    _fail(capsys, ["archive", "list", "--db", str(record)], record)
    _fail(capsys, ["history", "X", "--db", db, "--json", str(record)], record)
    _fail(capsys, ["history", "X", "--db", db, "--plot", str(proto)], proto)
    _fail(capsys, ["reanalyze", str(tmp_path), "--db", str(record)], record)
    _fail(capsys, ["emulate", "--truth", str(record), "--duration-s", "0"], record)
    _fail(capsys, ["acquire", "-o", str(record), "--sensor", "x", "--platform", "y"], record)
    # demo rewrites its own record, not a record that no demo wrote
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "record.csv").write_text(RECORD_HEAD, encoding="utf-8")
    _fail(capsys, ["demo", "--out", str(tmp_path / "d")], tmp_path / "d")
    assert record.read_bytes() == rec_before


def test_report_refuses_its_inputs_and_records(proto, record, tmp_path, capsys):
    res = tmp_path / "r.json"
    assert main(["calibrate", str(proto), "-q", "-o", str(res)]) == 0
    _fail(capsys, ["report", str(res), "-o", str(res)], res)
    _fail(capsys, ["report", str(res), "-o", str(record)], record)
    # a result is recomputable: writing a result over a result is allowed
    assert main(["calibrate", str(proto), "-q", "-o", str(res)]) == 0


def test_check_outputs():
    check_outputs(["a.csv"], ["b.json", None])  # nothing exists: nothing to refuse
    with pytest.raises(OutputError, match="two outputs"):
        check_outputs([], ["x.json", "./x.json"])
    with pytest.raises(OutputError, match="input"):
        check_outputs(["d/../a.csv"], ["a.csv"])


def test_sniff_format(proto, record, tmp_path):
    assert sniff_format(proto) == "chekan-protocol/1"
    assert sniff_format(record) == "chekan-record/1"
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf# serial: 1\r\n# format: chekan-record/1\r\n")
    assert sniff_format(bom) == "chekan-record/1"
    late = tmp_path / "late.csv"  # a format line after the data is not a header
    late.write_text("t_s\n# format: chekan-record/1\n")
    assert sniff_format(late) is None
    assert sniff_format(tmp_path / "missing") is None


def test_atomic_output_keeps_the_old_file_on_failure(tmp_path):
    p = tmp_path / "r.json"
    p.write_text("old")
    with pytest.raises(RuntimeError), atomic_output(p) as f:
        f.write("half")
        raise RuntimeError("interrupted")
    assert p.read_text() == "old"
    assert os.listdir(tmp_path) == ["r.json"]  # no temporary file left
    with atomic_output(p) as f:
        f.write("new")
    assert p.read_text() == "new"
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~mask  # not mkstemp's 0600


def test_result_writer_is_atomic(proto, tmp_path, monkeypatch):
    from chekan.files import durable
    from chekan.results.document import write_result

    res = tmp_path / "r.json"
    assert main(["calibrate", str(proto), "-q", "-o", str(res)]) == 0
    before = res.read_bytes()

    def crash(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(durable.os, "fsync", crash)
    with pytest.raises(OSError):
        write_result(res, {"format": "x"})
    assert res.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["calibr_46.csv", "r.json"]


def test_netcdf_written_atomically(tmp_path):
    az = pytest.importorskip("arviz")
    import numpy as np

    from inference.arviz_io import load_netcdf, save_netcdf

    p = tmp_path / "post.nc"
    save_netcdf(az.from_dict(posterior={"x": np.zeros((1, 5))}), p)
    assert os.listdir(tmp_path) == ["post.nc"]
    assert load_netcdf(p).posterior["x"].shape == (1, 5)


# ------------------------------------------------------------------ 2. closed pipe
@pytest.mark.parametrize(
    "cmd",
    [
        ["-m", "chekan.cli", "program"],
        ["-m", "chekan.archive", "archive", "list"],
        ["-m", "hw.cli", "--help"],
    ],
)
def test_closed_stdout_ends_quietly(cmd, tmp_path):
    from chekan.archive.db import Archive

    Archive(tmp_path / "a.sqlite").close()  # reading commands refuse a missing archive
    env = {**os.environ, "PYTHONPATH": str(ROOT), "CHEKAN_ARCHIVE": str(tmp_path / "a.sqlite")}
    p = subprocess.Popen(
        [sys.executable, *cmd], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env
    )
    p.stdout.close()  # the reader is gone before the command writes anything
    err = p.stderr.read().decode()
    rc = p.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert rc in (0, 141)
    if cmd[1] != "hw.cli":
        assert rc == 141


# ------------------------------------------------------------------ 3. exit status
def test_every_exit_status_is_documented():
    help_text = build_parser().format_help()
    assert EXIT_STATUS.strip() in help_text
    for code in (0, 1, 2, 3, 4, 130, 141):
        assert f"\n  {code} " in EXIT_STATUS
    assert "history" in EXIT_STATUS.split("\n  4 ")[1].split("\n")[0]
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert "4 an ALARM" in sub.choices["history"].format_help()
    assert "3 not converged" in sub.choices["calibrate"].format_help()
    assert "1 some inputs failed" in sub.choices["reanalyze"].format_help()


def test_exit_0_and_2(proto, tmp_path, capsys):
    assert main(["calibrate", str(proto), "-q"]) == 0
    assert main(["calibrate", str(tmp_path / "missing.csv")]) == 2
    assert "missing.csv" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["calibrate", "--no-such-option"])
    assert e.value.code == 2


def test_exit_1_when_some_inputs_fail(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    assert main(["archive", "add", str(bad), "--db", str(tmp_path / "a.sqlite")]) == 1


def test_exit_3_strict_not_converged(proto, monkeypatch):
    import chekan.pipeline as pipeline

    real = pipeline.calibrate_file

    def not_converged(path, opts):
        res = real(path, opts)
        res["diagnostics"]["converged"] = False
        return res

    monkeypatch.setattr(pipeline, "calibrate_file", not_converged)
    assert main(["calibrate", str(proto), "-q"]) == 0
    assert main(["calibrate", str(proto), "-q", "--strict"]) == 3


def test_exit_4_alarm(tmp_path, monkeypatch):
    import chekan.archive.history as history
    from chekan.archive.db import Archive

    Archive(tmp_path / "a.sqlite").close()  # history refuses a missing archive
    hist = {"alarms": [{"level": "ALARM"}]}
    monkeypatch.setattr(history, "stability_history", lambda *a, **k: hist)
    monkeypatch.setattr(history, "format_history", lambda h: "ALARM")
    assert main(["history", "46", "--db", str(tmp_path / "a.sqlite")]) == 4
    hist["alarms"] = [{"level": "WARNING"}]
    assert main(["history", "46", "--db", str(tmp_path / "a.sqlite")]) == 0


def test_exit_130_interrupted(monkeypatch, capsys):
    import chekan.cli.commands as cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_cmd_program", interrupted)
    assert main(["program"]) == 130
    assert "interrupted" in capsys.readouterr().err


# ------------------------------------------------------------------ 5. short options
SHORT = {"--quiet": "-q", "--out": "-o", "--jobs": "-j", "--version": "-V", "--verbose": "-v"}


def _parsers(p: argparse.ArgumentParser):
    yield p
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            for sp in a.choices.values():
                yield from _parsers(sp)


def _all_parsers():
    from chekan.archive.cli import add_parsers
    from chekan.study.coverage import main as validate_main
    from hw.cli import build_parser as hw_parser

    yield from _parsers(build_parser())
    yield from _parsers(hw_parser())
    ap = argparse.ArgumentParser()
    add_parsers(ap.add_subparsers())
    yield from _parsers(ap)
    del validate_main  # its parser is built inside main(): checked by test_validate_short


def test_short_options_are_the_same_everywhere():
    seen = set()
    for p in _all_parsers():
        for a in p._actions:
            for long, short in SHORT.items():
                if long in a.option_strings:
                    assert short in a.option_strings, f"{p.prog}: {long} without {short}"
                    seen.add(long)
                elif short in a.option_strings and not (
                    short == "-o" and p.prog == "chekan calibrate" and "--json" in a.option_strings
                ):  # calibrate's main output is its result JSON
                    pytest.fail(f"{p.prog}: {short} means {a.option_strings}, not {long}")
    assert seen == set(SHORT)


def test_short_options_parse():
    ap = build_parser()
    a = ap.parse_args(["calibrate", "x.csv", "-q", "-o", "r.json"])
    assert a.quiet and a.json == "r.json"
    a = ap.parse_args(["reanalyze", "d", "-j", "2", "-q"])
    assert a.jobs == 2 and a.no_progress
    assert ap.parse_args(["acquire", "-q", "-o", "r.csv"]).out == "r.csv"
    assert ap.parse_args(["report", "r.json", "-o", "c.pdf"]).out == "c.pdf"
    assert ap.parse_args(["archive", "export", "-o", "x.csv"]).out_opt == "x.csv"


def test_version(capsys):
    from chekan import __version__

    with pytest.raises(SystemExit) as e:
        main(["-V"])
    assert e.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_validate_short_options(tmp_path, capsys, record):
    from chekan.study.coverage import main as validate_main

    with pytest.raises(SystemExit):
        validate_main(["-V"])
    shutil.copy(record, tmp_path / "validation.json")
    rc = validate_main(["-o", str(tmp_path), "-j", "1", "-q", "--sessions", "1"])
    assert rc == 2 and "validation.json" in capsys.readouterr().err


def test_a_bad_input_starts_no_background_loads(tmp_path, monkeypatch):
    """The stored executables are preloaded only once the input has been read: a bad file
    fails at once instead of waiting, at exit, for loads it will never use."""
    from chekan.errors import ChekanError
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.runtime import process

    started = []
    store = process.executable_store()
    monkeypatch.setattr(type(store), "preload", lambda self, label: started.append(label) or 0)
    bad = tmp_path / "bad.csv"
    bad.write_text("# format: chekan-record/1\n# garbage\nx,y\n1,2\n", encoding="utf-8")
    with pytest.raises(ChekanError, match=r"bad\.csv:2"):
        calibrate_file(bad, CalibrationOptions(method="map", progress=False))
    assert started == []


# ------------------------------------------------------------------ 4. end of process
def _end_process_run(body: str, tmp_path) -> subprocess.CompletedProcess:
    code = "import sys, threading, time\nfrom chekan.files.outputs import end_process\n" + body
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60
    )


def test_end_process_flushes_and_keeps_the_status(tmp_path):
    r = _end_process_run("print('done', end='')\nend_process(3)", tmp_path)
    assert (r.returncode, r.stdout, r.stderr) == (3, "done", "")


def test_end_process_waits_for_a_thread_with_work(tmp_path):
    """A non-daemon thread still running is work in flight: the ordinary exit joins it."""
    out = tmp_path / "late.txt"
    body = (
        f"threading.Thread(target=lambda: (time.sleep(0.5), open({str(out)!r}, 'w').write('x')))"
        ".start()\nend_process(0)"
    )
    r = _end_process_run(body, tmp_path)
    assert r.returncode == 0 and out.read_text() == "x"


def test_end_process_cuts_short_an_unneeded_preload(tmp_path):
    """A preload of executables (an ``aot-`` thread) is not waited for."""
    body = "threading.Thread(target=time.sleep, args=(30,), name='aot-x-0').start()\nend_process(5)"
    t = time.perf_counter()
    r = _end_process_run(body, tmp_path)
    assert r.returncode == 5 and time.perf_counter() - t < 20


def test_quiet_prints_nothing_on_success(tmp_path, capsys):
    """-q: nothing on standard output when the command succeeds, in every command that
    writes files (issue 33 §6), and the files are there."""
    from chekan.cli.commands import main

    paper = PROTOCOL
    res = tmp_path / "r.json"
    prog = tmp_path / "p.toml"
    prog.write_text('angles = ["2°30\'"]\ndwell_s = 60\nsettle_s = 20\nrounds = 1\n')
    db = tmp_path / "a.sqlite"
    folder = tmp_path / "old"
    folder.mkdir()
    shutil.copy(paper, folder / "calibr_46.csv")
    runs = [
        ["calibrate", "-q", str(paper), "-o", str(res)],
        ["simulate", "-q", "--program", str(prog), "-o", str(tmp_path / "s.csv")],
        ["report", "-q", str(res), "--out", str(tmp_path / "c.html")],
        ["archive", "add", "-q", "--db", str(db), str(res)],
        ["archive", "export", "-q", "--db", str(db), str(tmp_path / "e.csv")],
        ["reanalyze", "-q", "-j", "1", str(folder), "--db", str(tmp_path / "b.sqlite")],
    ]
    for argv in runs:
        assert main(argv) == 0, argv
        assert capsys.readouterr().out == "", argv
    for name in ("s.csv", "c.html", "a.sqlite", "e.csv", "b.sqlite"):
        assert (tmp_path / name).stat().st_size > 0, name


def test_simulate_writes_late_angles_and_a_moving_platform_from_the_command_line(tmp_path, capsys):
    """``--report-period-s``, ``--report-phase-s`` and ``--motion-substeps`` reach the
    simulator (the truth file states them, the record equals the one simulated in Python);
    a phase outside the period, or a period below a millisecond or above an hour, is
    refused with exit 2."""
    import json

    import numpy as np

    from chekan.physics.program import load_program
    from chekan.records import read_record
    from chekan.records.simulate import Truth, simulate_session

    toml = tmp_path / "p.toml"
    toml.write_text(
        'name = "short"\nangles = ["4°30\'"]\ndwell_s = 120\nsettle_s = 60\nrounds = 1\n',
        encoding="utf-8",
    )
    prog = load_program(toml)
    out, truth = tmp_path / "r.csv", tmp_path / "t.json"
    argv = ["simulate", "-o", str(out), "--truth", str(truth), "--program", str(toml)]
    argv += ["--seed", "3", "--report-period-s", "1", "--report-phase-s", "0.25"]
    assert main([*argv, "--motion-substeps", "3", "-q"]) == 0
    t = json.loads(truth.read_text(encoding="utf-8"))
    assert (t["platform_report_period_s"], t["platform_report_phase_s"]) == (1.0, 0.25)
    assert t["motion_substeps"] == 3
    want, _ = simulate_session(
        prog,
        Truth(
            serial="SIM-1",
            platform_report_period_s=1.0,
            platform_report_phase_s=0.25,
            motion_substeps=3,
        ),
        seed=3,
    )
    got = read_record(out)  # the file's resolution: 0.01″, 0.0001 pix
    np.testing.assert_allclose(got.tilt_y_arcsec, want.tilt_y_arcsec, atol=0.005 + 1e-9)
    np.testing.assert_allclose(got.m1_pix, want.m1_pix, atol=0.00005 + 1e-9)
    bad = [*argv[:-4], "--report-period-s", "1", "--report-phase-s", "1"]
    assert main([*bad[:1], "-o", str(tmp_path / "x.csv"), *bad[3:]]) == 2
    assert "--report-phase-s 1 must lie in [0, --report-period-s)" in capsys.readouterr().err
    # a period too short to mean anything is refused, not divided by (it overflowed)
    for period in ("1e-300", "0.0005", "5000"):
        tiny = [*argv[:-4], "--report-period-s", period]
        with pytest.raises(SystemExit) as stop:  # argparse's usage error
            main([*tiny[:1], "-o", str(tmp_path / "t.csv"), *tiny[3:]])
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert f"--report-period-s: {period} is neither 0 nor in [0.001, 3600]" in err
    assert not (tmp_path / "t.csv").exists()
