"""Two validation studies on the same platforms (``python -m chekan.study.compare``):
the RMS-error ratio and its paired bootstrap interval on hand-made rows, the pairing's
checks, the edge case split by shape, and the command's files and errors."""

import csv

import numpy as np
import pytest

from chekan.errors import ChekanError
from chekan.study.compare import compare, main, paired_rows
from chekan.study.scenario import (
    DEFAULT_SCENARIO,
    EDGE_SHAPES,
    edge_platform,
    session_truth,
)
from chekan.study.summary import PARAMS

CASES = ("typical", "edge")


def _study(errors: np.ndarray, sd: float, cases=CASES) -> list[dict]:
    """Rows of a map study whose session i has the error ``errors[i]`` in every parameter."""
    rows = []
    for i, e in enumerate(errors):
        row = {"session": i, "case": cases[i % len(cases)], "seed": i, "program": "p"}
        for p in PARAMS:
            row[f"true_{p}"] = 7.0 + 0.001 * i
            row[f"map_{p}"] = row[f"true_{p}"] + float(e)
            row[f"map_{p}_sd"] = sd
        rows.append(row)
    return rows


def _errors(n: int = 120, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, 1e-3, n)


def test_errors_half_the_others_on_every_session_give_a_ratio_of_one_half():
    err = _errors()
    rows = compare(_study(0.5 * err, 1e-3), _study(err, 2e-3), target=0.5)
    by = {(r.group, r.param): r for r in rows}
    for p in PARAMS:
        r = by[("all", p)]
        assert r.n == err.size
        assert r.ratio == pytest.approx(0.5, rel=1e-12)
        # every resample has the same ratio: the interval is the point
        assert r.low == pytest.approx(0.5, rel=1e-12) and r.high == pytest.approx(0.5, rel=1e-12)
        assert r.rms_b == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-12)
        assert r.z2_a == pytest.approx(np.mean((0.5 * err / 1e-3) ** 2), rel=1e-12)
        assert r.z2_b == pytest.approx(np.mean((err / 2e-3) ** 2), rel=1e-12)
    assert by[("typical", "b1")].n == err.size // 2


def test_the_interval_is_the_sampling_spread_of_the_ratio():
    """Independent errors of RMS 1 and 2 (× 1e-3) in n sessions: the ratio's interval holds
    0.5 and is about as wide as the delta method says (each RMS has relative sd 1/√(2n),
    their ratio 1/√n: 2·1.96·r/√n)."""
    n = 400
    a, b = _errors(n, 2), 2.0 * _errors(n, 3)
    r = next(x for x in compare(_study(a, 1e-3), _study(b, 1e-3)) if x.group == "all")
    assert r.low < 0.5 < r.high
    width = r.high - r.low
    expected = 2 * 1.96 * r.ratio / np.sqrt(n)
    assert 0.8 * expected < width < 1.25 * expected
    assert 0.0 < r.p_target < 1.0


def test_a_session_failed_in_either_study_is_left_out():
    err = _errors(30)
    a, b = _study(0.5 * err, 1e-3), _study(err, 1e-3)
    a[3]["map_b1"] = float("nan")
    b[7]["map_b1"] = float("nan")
    r = next(x for x in compare(a, b) if (x.group, x.param) == ("all", "b1"))
    assert r.n == 28
    assert r.ratio == pytest.approx(0.5, rel=1e-12)


def test_other_platforms_or_no_common_session_are_refused():
    err = _errors(10)
    a, b = _study(err, 1e-3), _study(err, 1e-3)
    b[4]["true_b1"] += 1e-6
    with pytest.raises(ChekanError, match=r"session 4 .*not the same platforms"):
        paired_rows(a, b, "map")
    other = [{**r, "seed": r["seed"] + 100} for r in _study(err, 1e-3)]
    with pytest.raises(ChekanError, match="share no session"):
        paired_rows(a, other, "map")
    with pytest.raises(ChekanError, match="--methods bayes"):
        paired_rows(a, _study(err, 1e-3), "bayes")


def test_the_edge_case_is_split_by_the_shape_its_sessions_were_simulated_with():
    err = _errors(80)
    rows = compare(_study(err, 1e-3), _study(err, 1e-3))
    groups = {r.group: r.n for r in rows if r.param == "b1"}
    edge = [i for i in range(80) if CASES[i % 2] == "edge"]
    shapes = [edge_platform(i)[0] for i in edge]
    for s in set(shapes):
        assert groups[f"edge: {s}"] == shapes.count(s)
    assert groups["edge"] == len(edge)
    # the helper is what the simulated session used
    truth = session_truth("edge", np.random.default_rng(0), 5, DEFAULT_SCENARIO)
    assert truth.angle_systematic_shape == edge_platform(5)[0] in EDGE_SHAPES
    assert truth.angle_error_sd_arcsec == edge_platform(5)[1]


def _write(path, rows):
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def test_the_command_prints_and_writes_the_table_and_names_a_bad_line(tmp_path, capsys):
    err = _errors(40)
    a, b, out = tmp_path / "a.csv", tmp_path / "b.csv", tmp_path / "ratio.md"
    _write(a, _study(0.5 * err, 1e-3))
    _write(b, _study(err, 1e-3))
    assert main([str(a), str(b), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed
    text = out.read_text(encoding="utf-8")
    assert "| all | b1 | 40 |" in text and "| 0.500 | 0.500–0.500 | 1.00 |" in text
    assert main([str(a), str(b), "-o", str(out)]) == 2  # never over an existing file
    assert "exists" in capsys.readouterr().err
    lines = b.read_text(encoding="utf-8").splitlines()
    fields = lines[5].split(",")
    fields[5] = "x1.2"  # map_b1 of session 4, the file's line 6
    lines[5] = ",".join(fields)
    b.write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert main([str(a), str(b)]) == 2
    assert f"{b}: line 6:" in capsys.readouterr().err
    (tmp_path / "c.csv").write_text("session,case\n0,typical\n", encoding="utf-8")
    assert main([str(a), str(tmp_path / "c.csv")]) == 2
    assert "not a validation.csv" in capsys.readouterr().err


def test_a_study_stopped_mid_write_loses_only_its_torn_last_line(tmp_path):
    """``read_rows`` (``--resume`` and this command read through it): an incomplete last
    line is left out with a warning; a short line elsewhere is an error naming it."""
    from chekan.study.coverage import read_rows

    path = tmp_path / "v.csv"
    _write(path, _study(_errors(5), 1e-3))
    text = path.read_text(encoding="utf-8")
    torn = tmp_path / "torn.csv"
    torn.write_text(text + "5,typical,5", encoding="utf-8")
    with pytest.warns(UserWarning, match=r"line 7: incomplete last line"):
        assert len(read_rows(torn)) == 5
    lines = text.splitlines()
    lines[2] = lines[2].rsplit(",", 3)[0]
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(ChekanError, match=r"short.csv: line 3: not the header's 13 fields"):
        read_rows(short)
