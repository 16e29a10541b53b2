"""Issue 57 §3: no output destroys a file of another kind that chekan reads or writes (a lab
file, a DCC, a PDF, …), none writes one format under another's suffix, and none creates a
missing folder: each is one line naming the path, exit 2, nothing written. A full disk
names the file and exits 1. CLI-level and cheap: the paper's protocol, the classical
method, the DCC and HTML certificates."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from chekan.cli.commands import main
from chekan.files import kinds as filekinds
from chekan.files.outputs import Output, OutputError, check_outputs, sniff_kind

LAB = """\
[lab]
name = "Gravimetry Lab"
email = "lab@example.org"
street = "Malaya Posadskaya 30"
city = "Saint Petersburg"
post_code = "197046"
country_code = "RU"
accreditation = "RA.RU.000000"

[responsible]
name = "I. Ivanov"
"""


@pytest.fixture
def made(tmp_path, paper_protocol, capsys) -> dict[str, Path]:
    """One file of each kind, each written by chekan (the lab file by hand)."""
    d = tmp_path
    proto = d / "calibr_46.csv"
    proto.write_bytes(Path(paper_protocol).read_bytes())
    lab = d / "lab.toml"
    lab.write_text(LAB, encoding="utf-8")
    res = d / "r.json"
    db = d / "a.sqlite"
    steps = [
        ["calibrate", str(proto), "-q", "-o", str(res)],
        ["report", str(res), "-q", "--format", "dcc", "--lab", str(lab), "-o", str(d / "c.xml")],
        ["report", str(res), "-q", "-o", str(d / "c.html")],
        ["archive", "add", "-q", str(res), "--db", str(db)],
        ["archive", "export", "-q", str(d / "e.csv"), "--db", str(db)],
        ["history", "46", "--db", str(db), "--json", str(d / "h.json")],
        ["simulate", "-q", "--program", str(_program(d)), "-o", str(d / "s.csv"), "--truth"],
    ]
    steps[-1].append(str(d / "t.json"))
    for argv in steps:
        assert main(argv) == 0, (argv, capsys.readouterr().err)
    (d / "c.pdf").write_bytes(b"%PDF-1.7\n%\xe2\xe3\xcf\xd3\n1 0 obj\n<<>>\nendobj\n")
    (d / "p.nc").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(64))
    capsys.readouterr()
    return {
        "protocol": proto,
        "lab": lab,
        "result": res,
        "dcc": d / "c.xml",
        "html": d / "c.html",
        "pdf": d / "c.pdf",
        "netcdf": d / "p.nc",
        "archive": db,
        "export": d / "e.csv",
        "record": d / "s.csv",
        "truth": d / "t.json",
        "history": d / "h.json",
        "program": d / "short.toml",
    }


def _program(d: Path) -> Path:
    p = d / "short.toml"
    p.write_text(
        'angles = ["2°30\'"]\naxis = "y"\norder = "+-"\ndwell_s = 60\nsettle_s = 30\nrounds = 1\n',
        encoding="utf-8",
    )
    return p


def _refused(capsys, argv: list[str], name: Path, why: str = "refusing") -> str:
    before = name.read_bytes() if name.is_file() else None
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert str(name) in err and why in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert (name.read_bytes() if name.is_file() else None) == before, f"{name} changed"
    return err


def test_each_kind_is_recognised(made):
    expect = {
        "protocol": filekinds.PROTOCOL,
        "lab": filekinds.LAB,
        "result": filekinds.RESULT,
        "dcc": filekinds.DCC,
        "html": filekinds.HTML,
        "pdf": filekinds.PDF,
        "netcdf": filekinds.NETCDF,
        "archive": filekinds.SQLITE,
        "export": filekinds.EXPORT,
        "record": filekinds.RECORD,
        "truth": filekinds.TRUTH,
        "history": filekinds.HISTORY,
        "program": filekinds.PROGRAM,
    }
    assert {k: sniff_kind(made[k]) for k in expect} == expect


def test_the_issues_cases_are_refused(made, tmp_path, capsys):
    proto, lab, dcc, res = made["protocol"], made["lab"], made["dcc"], made["result"]
    _refused(capsys, ["calibrate", str(proto), "-q", "-o", str(dcc)], dcc)
    _refused(capsys, ["calibrate", str(proto), "-q", "-o", str(lab)], lab)
    _refused(capsys, ["report", str(res), "-q", "-o", str(lab), "--format", "pdf"], lab)
    _refused(capsys, ["simulate", "-q", "-o", str(lab)], lab)
    # JSON into a .pdf name (no such file yet): refused by its suffix, nothing written
    pdf = tmp_path / "x.pdf"
    err = _refused(capsys, ["calibrate", str(proto), "-q", "-o", str(pdf)], pdf)
    assert ".json" in err and not pdf.exists()


@pytest.mark.parametrize("victim", ["dcc", "pdf", "html", "netcdf", "export", "truth", "lab"])
def test_no_output_replaces_a_file_of_another_kind(victim, made, capsys):
    proto, res, v = made["protocol"], made["result"], made[victim]
    _refused(capsys, ["calibrate", str(proto), "-q", "-o", str(v)], v)
    _refused(capsys, ["history", "46", "--db", str(made["archive"]), "--json", str(v)], v)
    _refused(capsys, ["design", "--json", str(v)], v)
    if victim != "export":
        _refused(capsys, ["archive", "export", str(v), "--db", str(made["archive"])], v)
    if victim not in ("dcc", "pdf", "html"):  # a certificate over a certificate: allowed
        _refused(capsys, ["report", str(res), "-q", "-o", str(v), "--format", "html"], v)


def test_outputs_contradicting_their_suffix_are_refused(made, tmp_path, capsys):
    proto, res = made["protocol"], made["result"]
    for name in ("r.xml", "r.toml", "r.csv", "r.sqlite", "r.png"):
        out = tmp_path / name
        _refused(capsys, ["calibrate", str(proto), "-q", "-o", str(out)], out)
        assert not out.exists()
    for argv, out in (
        (["simulate", "-q", "-o"], tmp_path / "s.json"),
        (["design", "-o"], tmp_path / "best.json"),
        (["report", str(res), "-q", "--format", "pdf", "-o"], tmp_path / "new.xml"),
        (["archive", "export", "--db", str(made["archive"]), "-o"], tmp_path / "e.json"),
        (["history", "46", "--db", str(made["archive"]), "--json"], tmp_path / "h.pdf"),
    ):
        _refused(capsys, [*argv, str(out)], out)
        assert not out.exists()


def test_a_file_of_the_same_kind_is_still_replaced(made, capsys):
    proto, res = made["protocol"], made["result"]
    assert main(["calibrate", str(proto), "-q", "-o", str(res)]) == 0
    html = made["html"]
    before = html.read_bytes()
    html.write_bytes(before + b"\n<!-- an older certificate -->\n")
    assert main(["report", str(res), "-q", "-o", str(html)]) == 0
    assert b"an older certificate" not in html.read_bytes()
    assert sniff_kind(html) == filekinds.HTML
    check_outputs(
        [],
        [
            Output(made["pdf"], writes=filekinds.PDF),
            Output(made["dcc"], writes=filekinds.DCC),
            Output(made["netcdf"], writes=filekinds.NETCDF),
            Output(made["export"], writes=filekinds.EXPORT),
            Output(made["truth"], writes=filekinds.TRUTH),
        ],
    )
    db, hist = made["archive"], made["history"]  # a history over a history: allowed
    assert main(["history", "46", "--db", str(db), "--json", str(hist)]) == 0
    with pytest.raises(OutputError, match="lab file"):
        check_outputs([], [Output(made["lab"], writes=filekinds.PROGRAM)])


def test_a_missing_folder_is_refused_and_not_created(made, tmp_path, capsys):
    proto, res, db = made["protocol"], made["result"], made["archive"]
    gone = tmp_path / "nonexistent" / "dir"
    cases = [
        ["calibrate", str(proto), "-q", "-o", str(gone / "r.json")],
        ["calibrate", str(proto), "-q", "--report", str(gone / "c.pdf")],
        ["report", str(res), "-q", "-o", str(gone / "c.pdf")],
        ["simulate", "-q", "-o", str(gone / "s.csv")],
        ["simulate", "-q", "-o", str(tmp_path / "s2.csv"), "--truth", str(gone / "t.json")],
        ["history", "46", "--db", str(db), "--plot", str(gone / "x.png")],
        ["history", "46", "--db", str(db), "--json", str(gone / "h.json")],
        ["archive", "export", str(gone / "e.csv"), "--db", str(db)],
        ["archive", "add", str(res), "--db", str(gone / "a.sqlite")],
        ["design", "--json", str(gone / "d.json")],
        ["design", "-o", str(gone / "best.toml")],
        ["emulate", "--truth", str(gone / "t.json"), "--duration-s", "0"],
        ["demo", "--out", str(gone / "demo")],
        ["acquire", "-o", str(gone / "rec.csv"), "--sensor", "/dev/null", "--platform", "x"],
    ]
    for argv in cases:
        err = _refused(capsys, argv, gone, "no such folder")
        assert not (tmp_path / "nonexistent").exists(), argv
        assert not (tmp_path / "s2.csv").exists()
    # a file where the folder should be
    (tmp_path / "flat").write_text("x", encoding="utf-8")
    err = _refused(
        capsys,
        ["calibrate", str(proto), "-q", "-o", str(tmp_path / "flat" / "r.json")],
        tmp_path / "flat",
        "not a folder",
    )
    assert "r.json" in err


def test_the_default_archive_folder_is_still_made(made, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("CHEKAN_ARCHIVE", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert main(["archive", "add", "-q", str(made["result"])]) == 0
    assert sniff_kind(tmp_path / "xdg" / "chekan" / "archive.sqlite") == filekinds.SQLITE


def _full_disk(monkeypatch) -> None:
    real = os.fsync

    def fsync(fd):  # the data reaches the disk at fsync: there it finds no room
        if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).endswith(".tmp"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)

    monkeypatch.setattr(os, "fsync", fsync)


@pytest.mark.parametrize("command", ["calibrate", "report"])
def test_a_full_disk_names_the_file_and_exits_1(command, made, tmp_path, monkeypatch, capsys):
    out = tmp_path / ("new.json" if command == "calibrate" else "new.html")
    argv = (
        ["calibrate", str(made["protocol"]), "-q", "-o", str(out)]
        if command == "calibrate"
        else ["report", str(made["result"]), "-q", "-o", str(out)]
    )
    _full_disk(monkeypatch)
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert f"{out}: " in err and "No space left on device" in err and "Traceback" not in err, err
    assert not out.exists() and not list(tmp_path.glob(".new.*.tmp"))
