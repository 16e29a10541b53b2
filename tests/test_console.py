"""Issue 33 §6: what the console says — labelled tables, silence with -q, an empty search."""

from __future__ import annotations

from pathlib import Path

import pytest

from chekan.cli.commands import main
from chekan.results.summary import ESTIMATES, format_summary


@pytest.fixture
def proto(tmp_path, paper_protocol) -> Path:
    p = tmp_path / "calibr_46.csv"
    p.write_bytes(Path(paper_protocol).read_bytes())
    return p


def test_quiet_prints_nothing_on_success(proto, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["calibrate", str(proto), "-q", "-o", str(out)]) == 0
    assert capsys.readouterr().out == "" and out.is_file()
    assert main(["calibrate", str(proto), "-o", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out


def test_every_table_of_the_summary_says_what_it_is(proto, tmp_path, capsys):
    from chekan.results.document import read_result

    out = tmp_path / "r.json"
    assert main(["calibrate", str(proto), "-q", "-o", str(out)]) == 0
    res = read_result(out)
    text = format_summary(res)
    assert f"estimates — {ESTIMATES['classical']}" in text
    assert "classical method (Calibr.exe), shown beside" not in text
    assert "scale factors per round (classical" in text
    res["method"] = "map"  # the joint methods print the classical tables beside their own
    text = format_summary(res)
    assert f"estimates — {ESTIMATES['map']}" in text
    assert text.index("estimates —") < text.index("classical method (Calibr.exe), shown beside")
    assert text.index("classical method (Calibr.exe), shown beside") < text.index("δg = da_ref")


@pytest.mark.parametrize(
    ("sampler", "named"), [("importance", "importance sampling"), ("emcee", "emcee")]
)
def test_the_posteriors_heading_names_the_sampler_that_ran(proto, tmp_path, capsys, sampler, named):
    from chekan.results.document import read_result

    out = tmp_path / "r.json"
    assert main(["calibrate", str(proto), "-q", "-o", str(out)]) == 0
    res = read_result(out)
    res["method"] = "bayes"
    res.setdefault("diagnostics", {})["sampler"] = sampler
    text = format_summary(res)
    assert f"estimates — joint model, posterior ({named}): mean, sd" in text
    other = "emcee" if sampler == "importance" else "importance sampling"
    assert f"posterior ({other})" not in text


def test_reanalyze_of_a_folder_without_inputs_says_so(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("no record here\n", encoding="utf-8")
    db = tmp_path / "a.sqlite"
    status = main(["reanalyze", str(tmp_path / "empty"), "--db", str(db), "-q"])
    err = capsys.readouterr().err
    assert status == 2 and "no chekan-record/1 or chekan-protocol/1 file found" in err, err
