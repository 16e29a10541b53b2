"""The archive database: schema, idempotent adds, posteriors kept beside it, CSV export, CLI."""

from __future__ import annotations

import copy
import json
import sqlite3
from pathlib import Path

import pytest

from chekan.archive.cli import main as archive_main
from chekan.archive.db import (
    SCHEMA_VERSION,
    Archive,
    default_db_path,
    migrate,
    read_export_csv,
    schema_version,
)
from chekan.errors import ChekanError
from chekan.pipeline import CalibrationOptions, calibrate_file
from chekan.results.document import write_result


@pytest.fixture(scope="module")
def result46(paper_protocol) -> dict:
    """The paper's protocol, classical: b1, b2 estimated, a held fixed."""
    return calibrate_file(paper_protocol, CalibrationOptions(method="classical", progress=False))


def variant(res: dict, *, sha: str | None = None, method: str | None = None, version=None):
    r = copy.deepcopy(res)
    if sha:
        r["record_sha256"] = sha
    if method:
        r["method"] = method
    if version:
        r["software"] = {"name": "chekan", "version": version}
    return r


def test_schema_wal_foreign_keys(tmp_path):
    with Archive(tmp_path / "a.sqlite") as a:
        assert schema_version(a.con) == SCHEMA_VERSION
        assert a.con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert a.con.execute("PRAGMA foreign_keys").fetchone()[0] == 1
        tables = {r[0] for r in a.con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        assert {"schema_version", "instruments", "sessions", "parameters"} <= tables
        assert migrate(a.con) == SCHEMA_VERSION  # idempotent
        a.con.execute("INSERT INTO schema_version VALUES (?, 'future')", (SCHEMA_VERSION + 1,))
    with pytest.raises(ChekanError, match="newer"):
        Archive(tmp_path / "a.sqlite")


def test_add_is_idempotent_on_hash_method_version(tmp_path, result46):
    with Archive(tmp_path / "a.sqlite") as a:
        sid = a.add_result(result46)
        assert a.add_result(copy.deepcopy(result46)) == sid
        assert a.add_result(variant(result46, version="9.9")) != sid
        assert a.add_result(variant(result46, method="map")) != sid
        assert len(a.list_sessions()) == 3
        s = a.get_session(sid)
        assert s["serial"] == "46" and s["calibrated_on"] == "2015-07-09"
        assert s["input_kind"] == "protocol" and s["input_sha256"] == result46["record_sha256"]
        assert s["result"]["parameters"]["b1"]["mean"] == result46["parameters"]["b1"]["mean"]
        assert s["metadata"]["platform_serial"] == "123456"
        p = s["parameters"]
        assert p["b1"]["fixed"] == 0 and p["b1"]["sd"] == result46["parameters"]["b1"]["sd"]
        assert p["a"]["fixed"] == 1 and p["a"]["sd"] is None  # held fixed by the protocol
        assert p["a"]["mean"] == result46["fixed"]["a"]
        with pytest.raises(sqlite3.IntegrityError):  # foreign key: instrument has sessions
            a.con.execute("DELETE FROM instruments")


def test_missing_hash_uses_the_input_file(tmp_path, result46):
    r = variant(result46)
    r["record_sha256"] = None
    with Archive(tmp_path / "a.sqlite") as a:
        sid = a.add_result(r)
        assert a.get_session(sid)["input_sha256"] == result46["record_sha256"]
        r["record"] = str(tmp_path / "gone.csv")
        with pytest.raises(ChekanError, match="cannot identify"):
            a.add_result(r)


def test_posterior_netcdf_is_copied_beside_the_archive(tmp_path, result46):
    nc = tmp_path / "results" / "run.nc"
    nc.parent.mkdir()
    nc.write_bytes(b"\x89HDF fake posterior")
    r = variant(result46, method="bayes")
    r["posterior_netcdf"] = "run.nc"  # relative to the result file
    rp = write_result(tmp_path / "results" / "run.json", r)
    db = tmp_path / "store" / "a.sqlite"
    with Archive(db) as a:
        sid = a.add_result(r, rp)
        s = a.get_session(sid)
        want = db.parent / "posteriors" / f"{result46['record_sha256']}_bayes.nc"
        assert Path(s["netcdf_path"]) == want and want.read_bytes() == nc.read_bytes()
        assert s["result_path"] == str(rp.resolve())
        sid2 = a.add_result(variant(r, version="0.9.0"), rp)  # never overwrites another's file
        assert Path(a.get_session(sid2)["netcdf_path"]).name.endswith("_0.9.0.nc")
        missing = variant(r, version="0.8.0")  # any version but the current one
        missing["posterior_netcdf"] = str(tmp_path / "nope.nc")
        with pytest.raises(ChekanError, match="not found"):
            a.add_result(missing, rp)
        assert len(a.list_sessions()) == 2


def test_export_csv_round_trip(tmp_path, result46):
    with Archive(tmp_path / "a.sqlite") as a:
        for i in range(3):
            r = variant(result46, sha=f"{i:064x}")
            r["date"] = f"201{i}-05-01"
            r["parameters"]["b1"]["mean"] += i * 1e-4 / 3  # not exactly representable in text
            a.add_result(r)
        n = a.export_csv(tmp_path / "out" / "all.csv")
        rows = a.parameter_rows()
        assert n == len(rows) == 9  # b1, b2, a (fixed) × 3
        assert read_export_csv(tmp_path / "out" / "all.csv") == rows
        assert a.export_csv(tmp_path / "none.csv", serial="nope") == 0
        assert [r["calibrated_on"] for r in a.list_sessions("46")] == [
            "2010-05-01",
            "2011-05-01",
            "2012-05-01",
        ]


def test_instrument_fields_follow_the_newest_session(tmp_path, result46):
    with Archive(tmp_path / "a.sqlite") as a:
        new = variant(result46, sha="1" * 64)
        new["date"] = "2020-01-01"
        new["metadata"]["platform_serial"] = "777"
        a.add_result(new)
        a.add_result(result46)  # older: does not overwrite
        (inst,) = a.instruments()
        assert inst["serial"] == "46" and inst["platform_serial"] == "777"


def test_default_path(monkeypatch, tmp_path):
    monkeypatch.delenv("CHEKAN_ARCHIVE", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert default_db_path() == tmp_path / "xdg" / "chekan" / "archive.sqlite"
    monkeypatch.setenv("CHEKAN_ARCHIVE", str(tmp_path / "env.sqlite"))
    assert default_db_path() == tmp_path / "env.sqlite"
    assert default_db_path(tmp_path / "x.sqlite") == tmp_path / "x.sqlite"


def test_cli_add_list_show_export(tmp_path, result46, capsys, monkeypatch):
    monkeypatch.setenv("CHEKAN_ARCHIVE", str(tmp_path / "env" / "a.sqlite"))
    rp = write_result(tmp_path / "r.json", result46)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert archive_main(["archive", "add", str(rp), str(rp)]) == 0
    assert capsys.readouterr().out.count("session 1") == 2
    assert archive_main(["archive", "add", str(bad)]) == 1
    assert "not valid JSON" in capsys.readouterr().err
    assert archive_main(["archive", "list", "--serial", "46"]) == 0
    out = capsys.readouterr().out
    assert "2015-07-09" in out and "6.982462" in out and "1 session(s)" in out
    assert archive_main(["archive", "show", "1"]) == 0
    assert "calibr_46_protocol.csv" in capsys.readouterr().out
    assert archive_main(["archive", "show", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["parameters"]["b2"]["unit"] == "mGal/pix"
    assert archive_main(["archive", "show", "5"]) == 2
    db = tmp_path / "other.sqlite"
    Archive(db).close()  # an empty archive (reading commands refuse a missing one)
    assert archive_main(["archive", "export", str(tmp_path / "x.csv"), "--db", str(db)]) == 0
    assert "0 parameter rows" in capsys.readouterr().out  # --db overrides $CHEKAN_ARCHIVE
    assert archive_main(["archive", "export", str(tmp_path / "y.csv")]) == 0
    assert len(read_export_csv(tmp_path / "y.csv")) == 3


def test_numpy_and_nan_values_are_stored_as_json(tmp_path, result46):
    import numpy as np

    r = variant(result46, sha="2" * 64)
    r["parameters"]["b1"]["mean"] = np.float64(r["parameters"]["b1"]["mean"])
    r["parameters"]["b2"]["sd"] = float("nan")
    r["reduced_error_percent"] = np.float32(0.019)
    with Archive(tmp_path / "a.sqlite") as a:
        s = a.get_session(a.add_result(r))
    assert s["result"]["parameters"]["b2"]["sd"] is None and s["parameters"]["b2"]["sd"] is None
    assert s["parameters"]["b1"]["mean"] == float(r["parameters"]["b1"]["mean"])


def test_the_platform_is_recorded_per_session(tmp_path, result46):
    """Each session keeps its own gyro-platform (schema v2); a v1 archive is upgraded with
    the platforms of its sessions' stored metadata."""
    db = tmp_path / "a.sqlite"
    with Archive(db) as a:
        old = variant(result46, sha="1" * 64)
        old["metadata"]["platform_serial"] = "P-1"
        new = variant(result46, sha="2" * 64)
        new["date"] = "2030-01-01"
        new["metadata"]["platform_serial"] = "P-2"
        s_old, s_new = a.add_result(old), a.add_result(new)
        assert a.get_session(s_old)["platform_serial"] == "P-1"
        assert a.get_session(s_new)["platform_serial"] == "P-2"
        assert [r["platform_serial"] for r in a.list_sessions()] == ["P-1", "P-2"]
        (inst,) = a.instruments()
        assert inst["platform_serial"] == "P-2"
    # a version-1 archive: the column is added and filled from the stored metadata
    v1 = tmp_path / "v1.sqlite"
    con = sqlite3.connect(v1, isolation_level=None)
    from chekan.archive.db import MIGRATIONS

    con.execute("CREATE TABLE schema_version (version INTEGER PRIMARY KEY, applied TEXT NOT NULL)")
    MIGRATIONS[1](con)
    con.execute("INSERT INTO schema_version VALUES (1, 'then')")
    con.execute("INSERT INTO instruments (serial) VALUES ('46')")
    con.execute(
        "INSERT INTO sessions (instrument_id, input_path, input_sha256, metadata_json, method,"
        " software_version, added, result_json) VALUES (1, 'x', 'h', ?, 'classical', '0.1',"
        " 'now', '{}')",
        (json.dumps({"platform_serial": "P-9"}),),
    )
    con.close()
    with Archive(v1, readonly=True) as a:  # a reading command upgrades it too
        assert schema_version(a.con) == SCHEMA_VERSION == 2
        assert a.list_sessions()[0]["platform_serial"] == "P-9"
