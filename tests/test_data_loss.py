"""Issue 33 §1, data loss: no output option overwrites the archive or an input of chekan;
reading commands never create or alter an archive; a differing result is not dropped
silently; files are complete whatever happens to standard output. CLI-level, cheap: the
paper's protocol and the classical method."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from chekan.archive.db import Archive
from chekan.cli.commands import main
from chekan.files.outputs import (
    PROGRAM,
    RESULT,
    SQLITE,
    Output,
    OutputError,
    check_outputs,
    sniff_kind,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def proto(tmp_path, paper_protocol) -> Path:
    p = tmp_path / "calibr_46.csv"
    p.write_bytes(Path(paper_protocol).read_bytes())
    return p


@pytest.fixture
def archived(tmp_path, proto, monkeypatch) -> tuple[Path, Path]:
    """(archive, result JSON): the protocol's classical result in an archive that is also
    the archive in use ($CHEKAN_ARCHIVE)."""
    res = tmp_path / "r.json"
    assert main(["calibrate", str(proto), "-q", "-o", str(res)]) == 0
    db = tmp_path / "archive.sqlite"
    assert main(["archive", "add", str(res), "--db", str(db)]) == 0
    monkeypatch.setenv("CHEKAN_ARCHIVE", str(db))
    return db, res


def _refused(capsys, argv: list[str], name: Path) -> None:
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert str(name) in err and "refusing" in err, err
    assert "Traceback" not in err


def _sessions(db: Path) -> int:
    with Archive(db, readonly=True) as a:
        return len(a.list_sessions())


def test_no_output_option_overwrites_the_archive(archived, proto, tmp_path, capsys):
    db, res = archived
    before = db.read_bytes()
    _refused(capsys, ["archive", "export", str(db)], db)  # the archive in use, by default
    _refused(capsys, ["archive", "export", "-o", str(db)], db)
    _refused(capsys, ["calibrate", str(proto), "-q", "-o", str(db)], db)
    _refused(capsys, ["calibrate", str(proto), "-q", "--report", str(db)], db)
    _refused(capsys, ["history", "46", "--json", str(db)], db)
    _refused(capsys, ["history", "46", "--plot", str(db)], db)
    _refused(capsys, ["report", str(res), "-o", str(db)], db)
    _refused(capsys, ["simulate", "--out", str(db)], db)
    _refused(capsys, ["design", "--json", str(db)], db)
    _refused(capsys, ["design", "-o", str(db)], db)
    _refused(capsys, ["emulate", "--truth", str(db), "--duration-s", "0"], db)
    # another archive, not the one in use, is protected the same way
    other = tmp_path / "other.sqlite"
    assert main(["archive", "add", str(res), "--db", str(other)]) == 0
    _refused(capsys, ["archive", "export", str(other)], other)
    assert db.read_bytes() == before and _sessions(db) == 1


def test_outputs_replace_a_result_or_program_only_with_their_kind(
    archived, proto, tmp_path, capsys
):
    _, res = archived
    prog = tmp_path / "p.toml"
    prog.write_text('name = "mine"\nangles = ["2°30\'"]\ndwell_s = 600\n', encoding="utf-8")
    assert sniff_kind(res) == RESULT and sniff_kind(prog) == PROGRAM
    keep = res.read_bytes(), prog.read_bytes()
    _refused(capsys, ["history", "46", "--json", str(res)], res)
    res2 = tmp_path / "r2.json"
    res2.write_bytes(res.read_bytes())
    _refused(capsys, ["report", str(res), "-o", str(res2)], res2)
    _refused(capsys, ["calibrate", str(proto), "-q", "-o", str(prog)], prog)
    _refused(capsys, ["archive", "export", str(prog)], prog)
    _refused(capsys, ["design", "--json", str(prog)], prog)
    assert (res.read_bytes(), prog.read_bytes()) == keep
    # a result over a result, a program over a program: recomputable, allowed
    check_outputs([], [Output(res, writes=RESULT), Output(prog, writes=PROGRAM)])
    with pytest.raises(OutputError, match="SQLite"):
        check_outputs([], [Output(archived[0], writes=RESULT)])
    check_outputs([], [Output(archived[0], writes=SQLITE)])  # the archive a command adds to


def test_reading_commands_refuse_a_missing_database(tmp_path, monkeypatch, capsys):
    typo = tmp_path / "typo.sqlite"
    monkeypatch.delenv("CHEKAN_ARCHIVE", raising=False)
    for argv in (
        ["archive", "list", "--db", str(typo)],
        ["archive", "show", "1", "--db", str(typo)],
        ["archive", "export", str(tmp_path / "o.csv"), "--db", str(typo)],
        ["history", "46", "--db", str(typo)],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"{typo}: no archive database there" in err and "Traceback" not in err
        assert not typo.exists() and not (tmp_path / "o.csv").exists()


def test_a_file_that_is_no_archive_is_a_clear_error(tmp_path, capsys):
    junk = tmp_path / "notes.sqlite"
    junk.write_text("not a database at all\n" * 50, encoding="utf-8")
    other = tmp_path / "other.sqlite"
    sqlite3.connect(other).execute("CREATE TABLE t (x)").connection.close()
    for db, why in ((junk, "not an SQLite database"), (other, "no chekan archive")):
        before = db.read_bytes()
        assert main(["archive", "list", "--db", str(db)]) == 2
        err = capsys.readouterr().err
        assert f"{db}: " in err and why in err and "Traceback" not in err, err
        assert db.read_bytes() == before
    assert main(["archive", "add", str(tmp_path / "none.json"), "--db", str(junk)]) == 2
    err = capsys.readouterr().err
    assert "not an SQLite database" in err and "Traceback" not in err


def test_a_read_only_archive_is_read_and_not_written(archived, monkeypatch, capsys):
    db, res = archived
    assert main(["archive", "list"]) == 0
    capsys.readouterr()
    real = sqlite3.connect

    def read_only(*args, **kwargs):  # root may write any file: make SQLite refuse instead
        con = real(*args, **kwargs)
        con.execute("PRAGMA query_only = ON")
        return con

    monkeypatch.setattr("chekan.archive.db.sqlite3.connect", read_only)
    assert main(["archive", "list"]) == 0
    changed = json.loads(res.read_text(encoding="utf-8"))
    changed["record_sha256"] = "0" * 64
    res.write_text(json.dumps(changed), encoding="utf-8")
    assert main(["archive", "add", str(res)]) == 2
    err = capsys.readouterr().err
    assert f"{db}: the archive cannot be written" in err and "Traceback" not in err, err


def test_a_differing_result_is_reported_and_replaced_on_request(archived, tmp_path, capsys):
    db, res = archived
    with Archive(db, readonly=True) as a:
        (sid,) = [s["id"] for s in a.list_sessions()]
        b1 = a.get_session(sid)["parameters"]["b1"]["mean"]
    changed = json.loads(res.read_text(encoding="utf-8"))
    changed["parameters"]["b1"]["mean"] = b1 * (1 + 1e-4)
    changed["created"] = "2030-01-01T00:00:00Z"
    other = tmp_path / "r2.json"
    other.write_text(json.dumps(changed), encoding="utf-8")
    # the same numbers written at another time: the same session, quietly
    same = json.loads(res.read_text(encoding="utf-8"))
    same["created"] = "2031-01-01T00:00:00Z"
    (tmp_path / "same.json").write_text(json.dumps(same), encoding="utf-8")
    assert main(["archive", "add", str(tmp_path / "same.json")]) == 0
    assert f"session {sid}" in capsys.readouterr().out

    assert main(["archive", "add", str(other)]) == 1
    err = capsys.readouterr().err
    assert f"differs from archived session {sid}" in err and "--replace" in err, err
    with Archive(db, readonly=True) as a:
        assert a.get_session(sid)["parameters"]["b1"]["mean"] == b1

    assert main(["archive", "add", "--replace", str(other)]) == 0
    assert f"session {sid}" in capsys.readouterr().out
    with Archive(db, readonly=True) as a:
        assert [s["id"] for s in a.list_sessions()] == [sid]
        s = a.get_session(sid)
        assert s["parameters"]["b1"]["mean"] == b1 * (1 + 1e-4)
        assert s["result"]["created"] == "2030-01-01T00:00:00Z"


@pytest.mark.parametrize("command", ["calibrate", "history"])
def test_files_are_complete_when_stdout_closes_early(archived, proto, tmp_path, command):
    db, _ = archived
    out = tmp_path / "t.json"
    argv = {
        "calibrate": ["calibrate", str(proto), "-o", str(out)],
        "history": ["history", "46", "--json", str(out), "--db", str(db)],
    }[command]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen(
        [sys.executable, "-m", "chekan.cli", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    p.stdout.close()  # `| head` that has read enough before anything was printed
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 141, err
    assert "Traceback" not in err, err
    data = json.loads(out.read_text(encoding="utf-8"))  # complete JSON
    assert data["serial"] == "46" if command == "calibrate" else data
