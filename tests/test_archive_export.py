"""``chekan history SERIAL --export gravtools|csv FILE``: the scale factor as dated periods,
read back by the formats' rules; refusals of files and options."""

from __future__ import annotations

import copy
import csv
import datetime as dt
import json
import math
from pathlib import Path

import pandas as pd
import pytest

from chekan.archive.db import Archive
from chekan.archive.export import CSV_COLUMNS, OPEN_END
from chekan.cli.commands import main

# (date, relative change of b1 and b2 from the protocol's); two verifications on 2018-03-01;
# in the last session b2 was held fixed (no sd): it has no b2 to export
SESSIONS = [
    ("2015-07-09", 1.0),
    ("2016-07-09", 1.0002),
    ("2018-03-01", 1.0005),
    ("2018-03-01", 1.0006),
    ("2019-06-01", 1.0008),
]


@pytest.fixture(scope="module")
def archive(tmp_path_factory, paper_protocol) -> tuple[Path, list[dict]]:
    """An archive of instrument 46: the paper's protocol re-dated and rescaled five times."""
    from chekan.pipeline import CalibrationOptions, calibrate_file

    res = calibrate_file(paper_protocol, CalibrationOptions(method="classical", progress=False))
    db = tmp_path_factory.mktemp("export") / "a.sqlite"
    made = []
    with Archive(db) as a:
        for i, (date, f) in enumerate(SESSIONS):
            r = copy.deepcopy(res)
            r["record_sha256"], r["date"] = f"{i:x}" * 64, date
            for k in ("b1", "b2"):
                r["parameters"][k]["mean"] *= f
            if i == len(SESSIONS) - 1:
                r["parameters"]["b2"]["sd"] = None
            a.add_result(r)
            made.append(r)
    return db, made


def run(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        status = main(argv)
    except SystemExit as e:  # argparse: a bad option value
        status = int(e.code or 0)
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return status, out, err


# ---------------------------------------------------------------- GravTools' rules
# The rules of GravTools' gravimeter file, as its loader applies them (GravTools 0.3.7,
# gravtools/models/gravimeter.py: Gravimeters.add_from_json, Gravimeter.__init__,
# get_linear_scale_factor), restated here: a JSON list of gravimeters; these keys with
# exactly these types (an integer height offset is refused); ``calibration`` a list of
# periods with the four keys, dates read by pandas as UTC dates, inclusive at both ends, no
# two sharing a day; a reading's factor is that of the period holding its epoch's UTC date,
# and g_scaled = linear_factor × g.
GRAVIMETER_KEYS = {
    "type": str,
    "manufacturer": str,
    "serial_number": str,
    "height_offset_m": float,
    "description": str,
    "code": str,
}
PERIOD_KEYS = ("start_date", "end_date", "linear_factor", "comment")


def read_gravimeter_file(path: Path) -> dict[tuple[str, str], tuple[dict, pd.DataFrame]]:
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert isinstance(doc, list)
    out = {}
    for g in doc:
        for key, kind in GRAVIMETER_KEYS.items():
            assert isinstance(g[key], kind), (key, g[key])
        cal = g["calibration"]
        assert isinstance(cal, list) and cal
        df = pd.DataFrame([{k: c[k] for k in PERIOD_KEYS} for c in cal])
        for k in ("start_date", "end_date"):
            df[k] = pd.to_datetime(df[k], utc=True).dt.date
        for f in df["linear_factor"]:
            assert isinstance(f, float) and math.isfinite(f)
        assert all(isinstance(c, str) for c in df["comment"])
        for _, row in df.iterrows():
            assert row["start_date"] <= row["end_date"]
            inside = (
                (df["end_date"] <= row["end_date"]) & (df["end_date"] >= row["start_date"])
            ) | ((df["start_date"] <= row["end_date"]) & (df["start_date"] >= row["start_date"]))
            assert int(inside.sum()) == 1, df  # the period itself only: no overlap
        out[(g["type"], g["serial_number"])] = (g, df)
    return out


def factor_at(df: pd.DataFrame, epoch: str) -> float | None:
    day = pd.Timestamp(epoch, tz="UTC").date()
    hit = df[(df["start_date"] <= day) & (df["end_date"] >= day)]
    assert len(hit) <= 1
    return float(hit["linear_factor"].item()) if len(hit) else None


def _b(made: list[dict], i: int, key: str) -> float:
    return made[i]["parameters"][key]["mean"]


def _merged(made: list[dict], key: str, idx: tuple[int, ...]) -> tuple[float, float]:
    """Inverse-variance mean of sessions ``idx`` and its sd (Birge ratio ≥ 1)."""
    ps = [made[i]["parameters"][key] for i in idx]
    w = [1 / p["sd"] ** 2 for p in ps]
    m = sum(wi * p["mean"] for wi, p in zip(w, ps, strict=True)) / sum(w)
    chi2 = sum(wi * (p["mean"] - m) ** 2 for wi, p in zip(w, ps, strict=True))
    return m, max(1.0, math.sqrt(chi2 / (len(ps) - 1))) / math.sqrt(sum(w))


def test_gravtools_export_reads_back_by_gravtools_rules(archive, tmp_path, capsys):
    db, made = archive
    out = tmp_path / "gravimeters.json"
    argv = ["history", "46", "--db", str(db), "--at", "2020-01-01", "--export", "gravtools"]
    status, text, err = run(
        [*argv, str(out), "--system", "2", "--height-offset-m", "-0.25"], capsys
    )
    assert status in (0, 4), err
    assert f"wrote {out}" in text and "b_ref = " in text
    g, df = read_gravimeter_file(out)[("Chekan-AM", "46")]
    assert g["height_offset_m"] == -0.25 and "quartz system 2" in g["description"]
    # b2 exists on three dates (the last session held it fixed): three periods, each from
    # its verification to the day before the next, the last open (GravTools' 2100-01-01)
    assert [d.isoformat() for d in df["start_date"]] == ["2015-07-09", "2016-07-09", "2018-03-01"]
    assert [d.isoformat() for d in df["end_date"]] == ["2016-07-08", "2018-02-28", "2100-01-01"]
    # the factor is b2/b_ref, b_ref the first verification's b2, stated in the description
    b_ref = _b(made, 0, "b2")
    assert f"b_ref = {b_ref!r} mGal/pix" in g["description"]
    expected = [_b(made, 0, "b2"), _b(made, 1, "b2"), _merged(made, "b2", (2, 3))[0]]
    for f, b in zip(df["linear_factor"], expected, strict=True):
        assert f * b_ref == pytest.approx(b, rel=1e-9)
    # a survey's reading scaled as GravTools scales it
    assert factor_at(df, "2015-07-09T00:00:00") == 1.0
    assert factor_at(df, "2016-07-08T23:59:59") == 1.0
    assert factor_at(df, "2016-07-09T00:00:01") * 1000.0 == pytest.approx(1000.2, abs=1e-6)
    assert factor_at(df, "2015-07-08T23:59:59") is None  # before the first verification
    # the comments trace each period to its sessions and records
    assert "session 3, 4" in df["comment"][2] and "2" * 64 in df["comment"][2]


def test_gravtools_reference_b_and_the_last_period(archive, tmp_path, capsys):
    db, made = archive
    out = tmp_path / "g1.json"
    argv = ["history", "46", "--db", str(db), "--export", "gravtools", str(out), "--system", "1"]
    status, text, err = run(
        [*argv, "--reference-b", "6.9", "--valid-until", "2020-12-31", "--param", "b1"], capsys
    )
    assert status in (0, 4), err
    assert "give --height-offset-m" in text  # 0.0 written, and said so
    g, df = read_gravimeter_file(out)[("Chekan-AM", "46")]
    assert g["height_offset_m"] == 0.0 and "quartz system 1" in g["description"]
    assert len(df) == 4 and df["end_date"].iloc[-1] == dt.date(2020, 12, 31)
    assert df["linear_factor"].iloc[-1] * 6.9 == pytest.approx(_b(made, 4, "b1"), rel=1e-9)


def test_csv_export_reads_back(archive, tmp_path, capsys):
    db, made = archive
    out = tmp_path / "periods.csv"
    status, _, err = run(["history", "46", "--db", str(db), "--export", "csv", str(out)], capsys)
    assert status in (0, 4), err
    with open(out, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert [r["start_date"] for r in rows] == [
        "2015-07-09",
        "2016-07-09",
        "2018-03-01",
        "2019-06-01",
    ]
    assert [r["end_date"] for r in rows] == [
        "2016-07-08",
        "2018-02-28",
        "2019-05-31",
        OPEN_END.isoformat(),
    ]
    # exact round trip of the archived numbers, both systems, their standard uncertainties
    assert float(rows[0]["b1_mgal_per_pix"]) == _b(made, 0, "b1")
    assert float(rows[1]["b2_sd_mgal_per_pix"]) == made[1]["parameters"]["b2"]["sd"]
    m, sd = _merged(made, "b1", (2, 3))
    assert float(rows[2]["b1_mgal_per_pix"]) == pytest.approx(m, rel=1e-15)
    assert float(rows[2]["b1_sd_mgal_per_pix"]) == pytest.approx(sd, rel=1e-12)
    assert rows[2]["session_ids"] == "3;4" and rows[2]["record_sha256"] == "2" * 64 + ";" + "3" * 64
    assert "weighted mean of 2" in rows[2]["comment"]
    assert rows[3]["b2_mgal_per_pix"] == rows[3]["b2_sd_mgal_per_pix"] == ""  # held fixed
    assert {r["serial"] for r in rows} == {"46"} and {r["method"] for r in rows} == {"classical"}


def test_an_existing_file_is_replaced_only_by_an_export_of_its_kind(archive, tmp_path, capsys):
    db, _ = archive
    base = ["history", "46", "--db", str(db), "--param", "b1", "--export"]
    # a gravimeter file of the user's, with another instrument: never overwritten
    theirs = tmp_path / "gravimeters.json"
    foreign = [{"type": "CG5", "serial_number": "1", "description": "ours", "calibration": []}]
    theirs.write_text(json.dumps(foreign))
    before = theirs.read_bytes()
    status, _, err = run([*base, "gravtools", str(theirs), "--system", "1"], capsys)
    assert status == 2 and str(theirs) in err and len(err.strip().splitlines()) == 1, err
    assert theirs.read_bytes() == before
    # chekan's own export is replaced by a new one of its kind, not by a CSV
    ours = tmp_path / "export.json"
    for _ in range(2):
        status, _, err = run([*base, "gravtools", str(ours), "--system", "1"], capsys)
        assert status in (0, 4), err
    status, _, err = run([*base, "csv", str(ours)], capsys)
    assert status == 2 and str(ours) in err, err
    table = tmp_path / "t.csv"
    table.write_text("station,g_mgal\nA,1.0\n")
    status, _, err = run([*base, "csv", str(table)], capsys)
    assert status == 2 and str(table) in err and table.read_text().startswith("station"), err
    csv_out = tmp_path / "ok.csv"
    for _ in range(2):
        status, _, err = run([*base, "csv", str(csv_out)], capsys)
        assert status in (0, 4), err


@pytest.mark.parametrize(
    "extra,words",
    [
        (["--export", "gravtools", "X"], "--system 1 or --system 2"),
        (["--export", "csv", "X", "--system", "1"], "--system: for --export gravtools only"),
        (["--system", "2"], "--system: only with --export"),
        (["--export", "kml", "X"], "unknown format 'kml'"),
        (["--export", "csv", "X", "--valid-until", "2019-02-30"], "--valid-until"),
        (["--export", "csv", "X", "--valid-until", "2016-01-01"], "before the last verification"),
    ],
)
def test_export_options_are_checked(archive, tmp_path, capsys, extra, words):
    db, _ = archive
    extra = [str(tmp_path / "x") if a == "X" else a for a in extra]
    status, _, err = run(["history", "46", "--db", str(db), "--param", "b1", *extra], capsys)
    assert status == 2 and words in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x").exists()
