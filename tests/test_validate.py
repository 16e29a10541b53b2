"""The coverage study (``python -m chekan.study``): the summary on hand-made rows, and
small runs on simulated sessions (files, parallel workers, resume, honest MAP sds)."""

import csv
import json

import numpy as np
import pytest

from chekan.study.coverage import read_rows, run_study
from chekan.study.summary import (
    PARAMS,
    binomial_band,
    coverage_summary,
    format_summary,
    markdown_report,
)

# |z| values and how many sessions have them: 10 inside every interval (|z| ≤ 0.674),
# 8 inside the 90 % and 95 % ones only (0.674 < |z| ≤ 1.645), 1 inside the 95 % one only
# (1.645 < |z| ≤ 1.960) and 1 outside all: coverage exactly 10/20, 18/20 and 19/20.
Z_COUNTS = ((0.1, 10), (1.0, 8), (1.8, 1), (3.0, 1))


def _rows(sd: float = 2.0) -> list[dict]:
    """20 sessions with errors z·sd of alternating sign, z from ``Z_COUNTS``."""
    zs = [z for z, count in Z_COUNTS for _ in range(count)]
    rows = []
    for k, z in enumerate(zs):
        sign = 1 if k % 2 else -1
        row = {"session": k, "case": "typical"}
        for p in PARAMS:
            row[f"true_{p}"] = 5.0
            row[f"classical_{p}"] = 5.0 + sign * z * sd
            row[f"classical_{p}_sd"] = sd
        rows.append(row)
    return rows


def test_coverage_summary_on_constructed_z_scores():
    rows = _rows()
    rows.append({**rows[0], "classical_b1": np.nan})  # a failed session: left out of b1 only
    s = coverage_summary(rows, ["classical"])
    z2 = sum(z * z * c for z, c in Z_COUNTS) / 20
    for p in PARAMS:
        e = s[f"classical/{p}"]
        assert e["n"] == (20 if p == "b1" else 21)
    e = s["classical/b1"]
    assert e["coverage_50"] == pytest.approx(10 / 20, abs=1e-15)
    assert e["coverage_90"] == pytest.approx(18 / 20, abs=1e-15)
    assert e["coverage_95"] == pytest.approx(19 / 20, abs=1e-15)
    assert e["mean_z2"] == pytest.approx(z2, rel=1e-12)
    assert e["rms_error"] == pytest.approx(2.0 * np.sqrt(z2), rel=1e-12)
    assert e["rms_sd"] == pytest.approx(2.0, rel=1e-12)
    assert s["n_sessions"] == 21
    # binomial band: P(X ≤ lo·n) ≥ 0.0005, so an honest 90 % interval in 20 sessions
    # covers 13…20 of them
    assert e["bounds_90"] == [13 / 20, 1.0]
    lo, hi = binomial_band(1000, 0.5)
    assert 0.44 < lo < 0.5 < hi < 0.56
    # the methods present are found from the columns
    assert list(coverage_summary(_rows()).keys()) == [f"classical/{p}" for p in PARAMS] + [
        "n_sessions"
    ]
    text = format_summary(s)
    assert "classical/b1" in text and "0.95" in text


def test_coverage_of_the_stated_u_uses_each_rows_coverage_factor():
    """Where the rows carry the method's k (``<method>_<p>_k``: the MAP's t₉₅.₄₅(ν_eff)), the
    stated U = k·sd is scored against 95.45 %; k differs from session to session."""
    rows = _rows()
    for i, r in enumerate(rows):
        for p in PARAMS:  # |z| = 1.8 is inside U with k = 2.1, outside with k = 1.5
            r[f"classical_{p}_k"] = 2.1 if i % 2 else 1.5
    e = coverage_summary(rows, ["classical"])["classical/b1"]
    zs = [z for z, count in Z_COUNTS for _ in range(count)]
    want = np.mean([z <= (2.1 if i % 2 else 1.5) for i, z in enumerate(zs)])
    assert e["coverage_U"] == pytest.approx(want, abs=1e-15)
    assert e["bounds_U"] == list(binomial_band(20, 0.9545))
    assert e["mean_k"] == pytest.approx(1.8)
    assert "coverage_U" not in coverage_summary(_rows(), ["classical"])["classical/b1"]
    text = format_summary({"x": e, "n_sessions": 20})
    assert f"{want:.2f}" in text and "U (k)" in text


def test_markdown_flags_coverage_outside_the_band():
    rows = _rows()
    for r in rows:  # same errors, sds 10× too small: |z| = 1 (10 sessions), 10, 18, 30
        for p in PARAMS:
            r[f"classical_{p}_sd"] = 0.2
    good, bad = coverage_summary(_rows(), ["classical"]), coverage_summary(rows, ["classical"])
    assert bad["classical/b1"]["mean_z2"] == pytest.approx(100 * good["classical/b1"]["mean_z2"])
    settings = {
        "command": "test",
        "sessions": 20,
        "sessions_run": 20,
        "cases": ["typical"],
        "methods": ["classical"],
        "program": "p",
        "seed": 0,
        "jobs": 1,
        "seconds": 1.0,
        "mean_seconds": {"classical": 0.1},
        "failures": {"classical": 0},
    }
    md = markdown_report({"all": bad}, settings, ["coverage.png"])
    assert "| classical | b1 (mGal/pix) | 20 | **0.000** ! | **0.500** ! | **0.500** ! |" in md
    assert "![coverage](coverage.png)" in md
    md = markdown_report({"all": good}, settings)
    assert "| classical | b1 (mGal/pix) | 20 | 0.500 | 0.900 | 0.950 |" in md
    assert "!" not in md.split("## all")[1]


def _estimates(path):
    """CSV rows without the timing columns (which differ from run to run)."""
    return [{k: v for k, v in r.items() if not k.endswith("_seconds")} for r in read_rows(path)]


def test_classical_study_parallel_and_resumed_rows_are_identical(tmp_path):
    kw = dict(cases=("typical", "drift"), quick=True, seed=3, progress=False)
    a, b = tmp_path / "a", tmp_path / "b"
    s = run_study(4, a, methods=("classical",), jobs=2, **kw)
    # an interrupted run: the first two rows of the parallel one; resumed in this process
    lines = (a / "validation.csv").read_text().splitlines(keepends=True)
    b.mkdir()
    (b / "validation.csv").write_text("".join(lines[:3]))
    sb = run_study(4, b, methods=("classical",), resume=True, figures=False, **kw)
    assert sb["settings"]["sessions_run"] == 2
    assert _estimates(a / "validation.csv") == _estimates(b / "validation.csv")
    assert [r["case"] for r in read_rows(a / "validation.csv")] == ["typical", "drift"] * 2
    names = {p.rsplit("/", 1)[-1] for p in s["paths"]}
    assert names == {
        "validation.csv",
        "validation.json",
        "validation.md",
        "coverage.png",
        "z_hist.png",
        "errors.png",
    }
    for p in ("coverage.png", "z_hist.png", "errors.png"):
        assert (a / p).stat().st_size > 1000
    md = (a / "validation.md").read_text()
    for head in ("## all (4 sessions)", "## typical (2 sessions)", "## drift (2 sessions)"):
        assert head in md
    assert "seed | 3" in md
    js = json.loads((a / "validation.json").read_text())
    assert js["typical"]["n_sessions"] == 2 and js["settings"]["jobs"] == 2


def test_small_coverage_study_map(tmp_path):
    s = run_study(
        3, tmp_path, cases=("typical",), quick=True, seed=11, progress=False, figures=False
    )
    e = s["all"]
    # honest uncertainty: mean z² ≈ 1; a 3× underestimated sd would give ≈ 9
    for p in ("b1", "b2", "a"):
        assert e[f"map/{p}"]["mean_z2"] < 4.0, (p, e[f"map/{p}"])
        assert e[f"map/{p}"]["coverage_95"] >= 2 / 3
    # the joint model is at least as accurate as the classical fit on the same sessions
    for p in ("b1", "b2"):
        assert e[f"map/{p}"]["rms_error"] < 1.5 * e[f"classical/{p}"]["rms_error"]
    with open(tmp_path / "validation.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 and all(r["map_error"] == "" for r in rows)
    assert json.loads((tmp_path / "validation.json").read_text())["all"]["n_sessions"] == 3
    assert "| map | b1 (mGal/pix) | 3 |" in (tmp_path / "validation.md").read_text()


@pytest.mark.parametrize(
    ("args", "what"),
    [
        (["--calibration-scale-u-arcsec", "0"], "needs --calibration-u-arcsec"),
        (
            ["--calibration-u-arcsec", "0.5", "--calibration-scale-u-arcsec", "0.6"],
            "must be in [0, U]",
        ),
    ],
)
def test_a_scale_statement_needs_a_table_and_is_part_of_its_u(tmp_path, capsys, args, what):
    from chekan.study.coverage import main

    with pytest.raises(SystemExit) as e:
        main([*args, "--sessions", "1", "-o", str(tmp_path / "v")])
    assert e.value.code == 2 and what in capsys.readouterr().err
    assert not (tmp_path / "v").exists()  # refused before anything is written
