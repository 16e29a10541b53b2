"""End to end on a generated archive: three instruments over ten years, the paper's protocol
and broken files → batch re-analysis → archive → stability history."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import os
import re
import shutil
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from chekan.archive.cli import main as archive_main
from chekan.archive.db import Archive, read_export_csv
from chekan.archive.history import stability_history
from chekan.archive.reanalyze import find_inputs, reanalyze
from chekan.archive.synth import InstrumentSpec, write_archive_inputs
from chekan.results.document import sha256_file

SPECS = [
    InstrumentSpec("A-101", (6.98, 6.88), rate_ppm_per_year=50.0, seed=11),
    InstrumentSpec("B-202", (7.01, 6.93), rate_ppm_per_year=0.0, seed=22),
    InstrumentSpec("C-303", (6.90, 6.95), jumps=[("2016-01-01", 2500.0)], seed=33),
]
SESSIONS = 12


@pytest.fixture(scope="module")
def tree(tmp_path_factory, paper_protocol) -> dict:
    """Inputs: 36 simulated records, the protocol, a duplicate, broken and foreign files."""
    root = tmp_path_factory.mktemp("inputs")
    made = write_archive_inputs(root / "records", SPECS, sessions=SESSIONS, years=10.0)
    good = [p for v in made.values() for p, _ in v]
    (root / "legacy").mkdir()
    good.append(Path(shutil.copy(paper_protocol, root / "legacy" / "calibr_46_protocol.csv")))
    dup = Path(shutil.copy(good[0], root / "legacy" / "copy_of_first.csv"))

    bad = root / "broken"
    bad.mkdir()
    (bad / "truncated_header.csv").write_text(
        "# format: chekan-record/1\n# serial: 9\n# g_local_mgal: 981922.05\nt_s,m1_pix,m2"
    )
    lines = good[1].read_text().splitlines(keepends=True)
    row = next(i for i, x in enumerate(lines) if x[0].isdigit()) + 150  # a data row mid-file
    f = lines[row].split(",")
    f[1] = "12x.5"
    lines[row] = ",".join(f)
    (bad / "non_numeric.csv").write_text("".join(lines))
    (bad / "random.txt").write_text(
        "# format: chekan-record/1\nDear operator,\nthe platform was repaired on Monday.\n"
    )
    (bad / "future.csv").write_text("# format: chekan-record/7\n# serial: 1\n")
    # not inputs: ignored without a word
    (root / "README.md").write_text("# Calibrations of the fleet\n")
    (root / "legacy" / "scan.bin").write_bytes(os.urandom(512))
    (root / "legacy" / "old_result.json").write_text('{"format": "chekan-result/1"}')
    return {
        "root": root,
        "good": good,
        "dup": dup,
        "broken": {
            "truncated": (bad / "truncated_header.csv", 4),
            "non_numeric": (bad / "non_numeric.csv", row + 1),
            "random": (bad / "random.txt", 2),  # read as the column header
            "future": (bad / "future.csv", 1),
        },
    }


@pytest.fixture(scope="module")
def run1(tree, tmp_path_factory):
    db = tmp_path_factory.mktemp("store") / "archive.sqlite"
    rep = reanalyze(tree["root"], "classical", db=db, jobs=2, progress=False)
    return db, rep


def test_discovery_sniffs_the_format_line(tree):
    found, failures = find_inputs(tree["root"])
    assert len(found) == len(tree["good"]) + 1 + 3  # + duplicate + 3 broken claiming a format
    kinds = {p.name: k for p, k in found}
    assert kinds["calibr_46_protocol.csv"] == "protocol" and kinds["random.txt"] == "record"
    assert [Path(f.path).name for f in failures] == ["future.csv"]
    assert "future.csv:1: unsupported format 'chekan-record/7'" in failures[0].reason


def test_counts_and_failure_reasons(tree, run1):
    _, rep = run1
    assert rep.found == len(tree["good"]) + 1 + 3
    first, dup = str(tree["good"][0]), str(tree["dup"])
    (kept,) = {first, dup} & set(rep.done)  # two files, one content: analysed once
    (other,) = {first, dup} - {kept}
    assert sorted(rep.done) == sorted({str(p) for p in tree["good"][1:]} | {kept})
    assert rep.skipped == {other: f"same content as {kept}"}
    failed = {Path(f.path).name: f.reason for f in rep.failed}
    assert set(failed) == {p.name for p, _ in tree["broken"].values()}
    for path, line in tree["broken"].values():
        reason = failed[path.name]
        assert str(path) in reason  # the file …
        if line is not None:  # … and the line
            assert re.search(rf"{re.escape(str(path))}:{line}: ", reason), reason
    assert "not a number" in failed["non_numeric.csv"]
    assert "'m2_pix'" in failed["truncated_header.csv"]
    summary = rep.summary()
    assert f"done        {len(tree['good'])}" in summary and "failed       4" in summary


def test_second_run_skips_everything(tree, run1):
    db, _ = run1
    rep = reanalyze(tree["root"], "classical", db=db, jobs=2, progress=False)
    assert rep.done == {}
    assert len(rep.skipped) == len(tree["good"]) + 1
    assert all("already archived" in why for why in rep.skipped.values())
    assert len(rep.failed) == 4


def test_nothing_lost(tree, run1):
    db, rep = run1
    with Archive(db) as a:
        sessions = a.list_sessions()
        assert len(sessions) == len(tree["good"])
        by_sha = {}
        for s in sessions:
            by_sha.setdefault((s["input_sha256"], s["method"]), []).append(s)
        for p in tree["good"]:
            (s,) = by_sha[(sha256_file(p), "classical")]  # exactly one session per method
            assert s["id"] in (rep.done.get(str(p)), rep.done.get(str(tree["dup"])))
            assert Path(s["result_path"]).is_file()
            stored = a.get_session(s["id"])["result"]
            assert stored == json.loads(Path(s["result_path"]).read_text())
        counts = {i["serial"]: len(a.list_sessions(i["serial"])) for i in a.instruments()}
    assert counts == {"46": 1, **{sp.serial: SESSIONS for sp in SPECS}}


def test_export_round_trip(run1, tmp_path):
    db, _ = run1
    with Archive(db) as a:
        n = a.export_csv(tmp_path / "fleet.csv")
        rows = read_export_csv(tmp_path / "fleet.csv")
        assert rows == a.parameter_rows() and n == len(rows)
        a_only = a.export_csv(tmp_path / "a.csv", serial="A-101")
    assert {r["serial"] for r in read_export_csv(tmp_path / "a.csv")} == {"A-101"}
    assert a_only == len([r for r in rows if r["serial"] == "A-101"])


@pytest.mark.parametrize("spec", SPECS[:2], ids=lambda s: s.serial)
def test_trend_recovered_within_its_uncertainty(run1, spec):
    db, _ = run1
    with Archive(db) as a:
        hist = stability_history(a, spec.serial, params=("b1", "b2"), at="2021-01-01")
    for p in ("b1", "b2"):
        t = hist["parameters"][p]["trend"]
        r, sd = t["ppm_per_year"], t["sd_ppm_per_year"]
        assert abs(r - spec.rate_ppm_per_year) < 3 * sd, (p, r, sd)
        assert sd < 25.0  # informative: a 50 ppm/yr drift is resolved
    assert not [x for x in hist["alarms"] if x["kind"] == "change"]


def test_alarm_fires_for_injected_jump(run1):
    db, _ = run1
    with Archive(db) as a:
        hist = stability_history(a, "C-303", params=("b1", "b2"), tolerance_ppm=1200.0)
    for p in ("b1", "b2"):
        (alarm,) = [x for x in hist["alarms"] if x["kind"] == "change" and x["param"] == p]
        assert alarm["level"] == "ALARM"
        assert alarm["from"] < "2016-01-01" <= alarm["to"]
        assert alarm["delta_ppm"] == pytest.approx(2500, abs=600) and alarm["z"] > 5


def test_history_cli_plot_and_json(run1, tmp_path, capsys):
    db, _ = run1
    args = ["history", "A-101", "--db", str(db), "--at", "2021-01-01"]
    out = ["--plot", str(tmp_path / "h.png"), "--json", str(tmp_path / "h.json")]
    assert archive_main(args + out) == 0
    text = capsys.readouterr().out
    assert "trend" in text and "predicted at 2021-01-01" in text and "no alarm" in text
    assert (tmp_path / "h.png").stat().st_size > 10_000
    h = json.loads((tmp_path / "h.json").read_text())
    assert set(h["parameters"]) == {"b1", "b2", "a"}
    assert len(h["parameters"]["b1"]["points"]) == SESSIONS
    assert h["parameters"]["b1"]["prediction"]["date"] == "2021-01-01"
    assert archive_main(["history", "C-303", "--db", str(db), "--tolerance-ppm", "1200"]) == 4
    assert "ALARM: b1: change" in capsys.readouterr().out
    assert archive_main(["history", "nope", "--db", str(db)]) == 2


def test_history_fits_and_plot_leave_matplotlib_alone(run1, tmp_path):
    """The fitted model is public (``fits``, not in the JSON); drawing the plot does not
    switch the process's matplotlib backend (a notebook's inline plots keep working)."""
    import matplotlib

    from chekan.archive.history import plot_history, stability_history, write_history_json

    db, _ = run1
    with Archive(db) as archive:
        hist = stability_history(archive, "A-101", at="2021-01-01")
    b1 = hist["parameters"]["b1"]
    mean_ppm, sd_ppm = hist["fits"]["b1"].predict(np.array([0.0]))
    first = b1["points"][0]
    # the model's value at the first session lies within a few of that session's sd
    value = b1["reference"] * (1 + 1e-6 * mean_ppm[0])
    assert abs(value - first["mean"]) < 4 * first["sd"] and sd_ppm[0] > 0
    before = matplotlib.get_backend()
    matplotlib.use("svg")  # a backend other than Agg
    try:
        plot_history(hist, tmp_path / "h.png")
        assert matplotlib.get_backend() == "svg"
    finally:
        matplotlib.use(before)
    assert "fits" not in json.loads(write_history_json(tmp_path / "h.json", hist).read_text())


def test_dask_executor(tree, run1, tmp_path):
    pytest.importorskip(
        "dask.distributed", reason="dask[distributed] not installed (pip install 'chekan[dask]')"
    )
    from dask.distributed import LocalCluster

    sub = tmp_path / "subset"
    sub.mkdir()
    picked = tree["good"][::9]
    for p in picked:
        shutil.copy(p, sub / p.name)
    shutil.copy(tree["broken"]["non_numeric"][0], sub / "bad.csv")
    db, _ = run1
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster:
        rep = reanalyze(
            sub,
            "classical",
            db=tmp_path / "dask.sqlite",
            executor="dask",
            scheduler=cluster.scheduler_address,
            progress=False,
        )
    assert len(rep.done) == len(picked) and [Path(f.path).name for f in rep.failed] == ["bad.csv"]
    with Archive(tmp_path / "dask.sqlite") as d, Archive(db) as a:
        for p in picked:
            sha = sha256_file(p)
            mine = d.get_session(d.find(sha, "classical", rep.software_version))["parameters"]
            ref = a.get_session(a.find(sha, "classical", rep.software_version))["parameters"]
            assert mine["b1"]["mean"] == pytest.approx(ref["b1"]["mean"], rel=1e-12)


@pytest.mark.slow
def test_map_reanalysis(tree, run1, tmp_path):
    pytest.importorskip("chekan.joint", reason="chekan.joint (map/bayes methods) not available")
    sub = tmp_path / "one"
    sub.mkdir()
    shutil.copy(tree["good"][0], sub / "rec.csv")
    db, _ = run1
    rep = reanalyze(sub, "map", db=db, jobs=1, progress=False)
    assert not rep.failed and len(rep.done) == 1
    with Archive(db) as a:
        sha = sha256_file(tree["good"][0])
        methods = sorted(s["method"] for s in a.list_sessions() if s["input_sha256"] == sha)
        assert methods == ["classical", "map"]
        hist = stability_history(a, "A-101", params=("b1",))
    chosen = {pt["session_id"]: pt["method"] for pt in hist["parameters"]["b1"]["points"]}
    assert sorted(chosen.values()).count("map") == 1  # map preferred over classical


def test_reanalyze_workers_load_what_the_store_holds():
    """A worker's key of the executable store is its parent's (``XLA_FLAGS`` are part of
    it): ``reanalyze``'s workers load what ``chekan warmup`` stored. With XLA's intra-op
    threads switched off there, each worker compiled its bucket again (≈ 1 min)."""
    import multiprocessing as mp

    from chekan.archive.reanalyze import configure_worker_env
    from chekan.runtime import store

    ctx = mp.get_context("spawn")
    with cf.ProcessPoolExecutor(1, mp_context=ctx, initializer=configure_worker_env) as ex:
        theirs = ex.submit(store._machine).result(timeout=120)
    assert theirs == store._machine()


class CrashingPool(cf.Executor):
    """In-process stand-in for a process pool whose worker dies on a file named poison*:
    like BrokenProcessPool, every task of the pool from then on fails."""

    pools: ClassVar[list[CrashingPool]] = []

    def __init__(self, *args, **kwargs):
        self.broken = False
        self.tasks: list[list[str]] = []
        CrashingPool.pools.append(self)

    def submit(self, fn, *args, **kwargs):
        fut = cf.Future()
        chunk = args[0]
        self.tasks.append(list(chunk))
        self.broken |= any(Path(p).name.startswith("poison") for p in chunk)
        if self.broken:
            fut.set_exception(BrokenProcessPool("a worker died"))
        else:
            fut.set_result(fn(*args, **kwargs))
        return fut


def test_a_crashing_worker_fails_only_its_file(tree, tmp_path, monkeypatch):
    from chekan.archive import reanalyze as mod

    sub = tmp_path / "crash"
    sub.mkdir()
    for i, p in enumerate(tree["good"][:6]):
        shutil.copy(p, sub / (f"poison_{i}.csv" if i == 2 else p.name))

    @contextlib.contextmanager
    def fake(kind="local", jobs=None, scheduler=None):
        yield CrashingPool()

    CrashingPool.pools = []
    monkeypatch.setattr(mod, "make_executor", fake)
    rep = reanalyze(
        sub, "classical", db=tmp_path / "c.sqlite", chunk_size=2, progress=False, in_process=False
    )
    assert [Path(f.path).name for f in rep.failed] == ["poison_2.csv"]
    assert "worker crashed" in rep.failed[0].reason
    assert len(rep.done) == 5
    # pool 1 broke at the poison's chunk; its files and those after were retried one by one
    assert [len(t) for t in CrashingPool.pools[0].tasks] == [2, 2, 2]
    assert all(len(t) == 1 for pool in CrashingPool.pools[1:] for t in pool.tasks)


def test_small_classical_batches_run_in_process(tree, tmp_path, monkeypatch):
    """Spawning workers costs more than a few hundred classical fits: they run here, and a
    bad file still fails alone."""
    from chekan.archive import reanalyze as mod

    assert mod.run_in_process("classical", "local", 40, 2)
    assert not mod.run_in_process("classical", "local", 5000, 16)
    assert not mod.run_in_process("map", "local", 2, 2)
    assert not mod.run_in_process("classical", "dask", 2, 2)

    def no_workers(*a, **k):
        raise AssertionError("no worker pool for a small classical batch")

    monkeypatch.setattr(mod, "make_executor", no_workers)
    sub = tmp_path / "small"
    sub.mkdir()
    for p in tree["good"][:4]:
        shutil.copy(p, sub / p.name)
    shutil.copy(tree["broken"]["truncated"][0], sub / "bad.csv")
    rep = reanalyze(sub, "classical", db=tmp_path / "s.sqlite", jobs=2, progress=False)
    assert len(rep.done) == 4
    assert [Path(f.path).name for f in rep.failed] == ["bad.csv"]


def test_reanalyze_cli(tree, tmp_path, capsys):
    sub = tmp_path / "cli"
    sub.mkdir()
    shutil.copy(tree["good"][3], sub / "good.csv")
    shutil.copy(tree["broken"]["truncated"][0], sub / "bad.csv")
    db, res = tmp_path / "cli.sqlite", tmp_path / "res"
    args = ["reanalyze", str(sub), "--db", str(db), "--jobs", "1", "--results-dir", str(res)]
    assert archive_main([*args, "--no-progress"]) == 1  # a failure: exit status 1
    out = capsys.readouterr().out
    assert "done         1" in out and f"{sub / 'bad.csv'}:4: missing required column" in out
    (written,) = res.glob("good.*.classical-*.json")
    with Archive(db) as a:
        (s,) = a.list_sessions()
        assert s["result_path"] == str(written.resolve())
