"""Cheap checks of the benchmark helpers (``bench/``): the NumPy reference fit and the table."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.classical_ref import numpy_classical_fit
from bench.table import Row, format_table


def test_numpy_reference_agrees_with_the_classical_method(short_session):
    from chekan.classical.fit import calibrate_record

    _, rec, _ = short_session
    settle = float(rec.meta["program_settle_s"])
    cres, _ = calibrate_record(rec, settle_s=settle)
    b, a = numpy_classical_fit(rec, settle)
    assert b.shape == cres.b.shape == (2, 2)
    np.testing.assert_allclose(b, cres.b, rtol=1e-12)
    np.testing.assert_allclose(a, cres.a, rtol=1e-10)


def test_table_is_aligned():
    rows = [Row("classical fit", "12.6 ms", "4.7 ms NumPy ref.", "note"), Row("skip", "4213/s")]
    lines = format_table(rows, "title").splitlines()
    assert lines[0] == "title"
    assert len({line.index("  ", len("classical fit")) for line in lines[3:]}) == 1
    assert lines[4].split()[-1] == "—"


def test_main_prints_every_section(monkeypatch, tmp_path, capsys):
    """``python -m bench`` runs the CLI, calibration, posterior, archive and several-records
    benches into one table (each stubbed here; the slow tests below run the real ones)."""
    import bench.__main__ as bm

    def stub(name):
        return lambda *a, **k: [Row(f"{name} row", "1 s", "2 s ref.")]

    mods = ("cli_bench", "calibration_bench", "nuts_bench", "archive_bench", "several_records")
    for mod in mods:
        monkeypatch.setattr(getattr(bm, mod), "run", stub(mod))
    assert bm.main(["--quick", "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    for mod in mods:
        assert f"{mod} row" in out
    assert bm.main(["--skip-bayes", "--json", str(tmp_path / "r.json")]) == 0
    assert "nuts_bench row" not in capsys.readouterr().out


def test_cli_cache_dir_follows_jaxconfig(tmp_path):
    from bench.cli_bench import cache_dir

    assert cache_dir({"CHEKAN_JAX_CACHE": "0"}) is None
    assert cache_dir({"CHEKAN_JAX_CACHE": str(tmp_path)}) == tmp_path
    assert cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "chekan" / "jax"
    # "1" (and empty) mean the default folder, as in chekan/jaxconfig.py, never a folder "1"
    default = cache_dir({"XDG_CACHE_HOME": str(tmp_path), "CHEKAN_JAX_CACHE": "1"})
    assert default == tmp_path / "chekan" / "jax"


def test_jaxconfig_cache_dir_reads_1_as_the_default(tmp_path, monkeypatch):
    from chekan.jaxconfig import cache_dir

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("CHEKAN_JAX_CACHE", "1")
    assert cache_dir() == tmp_path / "chekan" / "jax"
    monkeypatch.setenv("CHEKAN_JAX_CACHE", "0")
    assert cache_dir() is None
    monkeypatch.setenv("CHEKAN_JAX_CACHE", str(tmp_path / "x"))
    assert cache_dir() == tmp_path / "x"


def test_posterior_agreement_measure():
    from bench.nuts_bench import agreement

    rng = np.random.default_rng(0)
    a = rng.standard_normal((2, 4000, 3))
    dm, ds = agreement(a, a + 0.5)
    assert abs(dm - 0.5) < 0.05 and ds < 1e-12
    dm, ds = agreement(a, 2 * a)
    assert ds > 0.9


@pytest.mark.slow
def test_cli_bench_prints_new_process_rows(tmp_path):
    """Two new ``chekan calibrate --method map`` processes; the figures are printed (their
    speed is not asserted)."""
    from bench.cli_bench import run

    rows = run(seed=0, skip_bayes=True, fresh_cache=False)
    labels = [r.label for r in rows]
    assert any("--method map` new process, first" in lab for lab in labels)
    assert any("--method map` new process, second" in lab for lab in labels)
    for r in rows[1:]:
        assert r.figure.endswith(" s") and r.reference == "goal ≤ 3 s"
        assert "JAX cache" in r.note


@pytest.mark.slow
@pytest.mark.skipif(
    not __import__("os").environ.get("CHEKAN_TEST_NUTS"),
    reason="NUTS on this posterior takes minutes on 2 cores (set CHEKAN_TEST_NUTS=1)",
)
def test_nuts_bench_smallest_settings_prints_its_rows():
    """The posterior bench at its smallest settings (3 h record, 2 short NUTS chains): the
    rows exist and carry numbers; speed and agreement are not asserted (too few draws)."""
    pytest.importorskip("blackjax")
    from bench.nuts_bench import run

    rows = run(seed=0, quick=True, chains=2, warmup=40, draws=40, n_eval=20)
    labels = [r.label for r in rows]
    assert labels[0].startswith("marginal log-density") and rows[0].reference == "goal 0.5 ms"
    assert labels[1].startswith("`bayes` in one warm process")
    assert "NUTS" in rows[1].reference and "ESS" in rows[1].figure
    assert "ESS/s" in labels[2] and rows[2].figure.endswith("/s emcee")
    assert rows[3].note in ("AGREE", "DISAGREE (beyond the tolerances)")
    assert np.isfinite(rows[3].values["max_abs_dmean_over_sd"])


def _check_several_records_rows(rows, methods=None):
    """The several-records table: a bare start, four records per method, the median and the
    worst beside the bare start, ESS/s per parameter, reanalyze throughput; finite values."""
    from bench.several_records import CASES, EMCEE

    methods = ("map", "bayes", EMCEE) if methods is None else methods

    labels = [r.label for r in rows]
    assert labels[0].startswith("simulate the 4 records")
    bare = rows[1]
    assert bare.label.startswith("bare JAX start") and np.isfinite(bare.values["seconds"])
    assert bare.values["seconds"] > 0
    for m in methods:
        rec_rows = [r for r in rows if r.label.startswith(f"`calibrate --method {m}`, ")]
        assert sorted(r.values["case"] for r in rec_rows) == sorted(CASES)
        per = [r for r in rec_rows if r.figure != "FAILED"]
        failed = [r.values["case"] for r in rec_rows if r.figure == "FAILED"]
        assert per, "every record failed"
        for r in per:
            assert np.isfinite(r.values["seconds"]) and r.values["seconds"] > 0
            assert r.values["ratio_to_bare"] == r.values["seconds"] / bare.values["seconds"]
        over = f"`calibrate --method {m}` over {len(per)} records"
        (summ,) = [r for r in rows if r.label.startswith(over)]
        v = summ.values
        assert v["failed"] == failed and all(c in summ.note for c in failed)
        assert v["worst_seconds"] == max(r.values["seconds"] for r in per)
        assert v["median_seconds"] == float(np.median([r.values["seconds"] for r in per]))
        assert np.isfinite(v["worst_ratio_to_bare"]) and np.isfinite(v["median_ratio_to_bare"])
        assert ("— met" in summ.note) == v["target_met"]
        if m in ("bayes", EMCEE):
            for r in per:
                if r.values["sampler"] == "emcee":
                    assert np.isfinite(r.values["tau_max"]) and r.values["n_steps"] > 0
                else:
                    assert r.values["sampler"] == "importance" and r.values["pareto_k"] < 0.7
                ess = r.values["ess_bulk"]
                assert "b1" in ess and all(np.isfinite(x) and x > 0 for x in ess.values())
                assert r.values["ess_per_s"]["b1"] == ess["b1"] / r.values["seconds"]
            per_m = f"bulk ESS per second per parameter, {m} ("
            (rate,) = [r for r in rows if r.label.startswith(per_m)]
            worst = rate.values["worst_ess_per_s"]
            assert all(np.isfinite(x) for x in worst.values())
            assert worst["b1"] == min(r.values["ess_per_s"]["b1"] for r in per)
    if "bayes" in methods:
        (re,) = [r for r in rows if r.label.startswith("`reanalyze --method bayes` over the 4")]
        assert 1 <= re.values["sessions"] <= 4 and np.isfinite(re.values["sessions_per_s"])


def test_several_records_table_from_stubbed_runs(monkeypatch):
    """Median, worst, ratios and ESS/s computed from the runs (processes stubbed: no timing)."""
    import bench.several_records as sr
    from chekan.physics.parameters import PARAMETER_UNITS

    secs = {"typical": 10.0, "misaligned": 14.0, "slow": 30.0, "dual-axis": 12.0}

    def fake_calibrate(case, rec, method, tmp, env):
        k = {"bayes": 1.0, sr.EMCEE: 1.5}.get(method, 0.1)
        run = sr.Run(case, method, secs[case] * k, 0.5 + 0.1 * len(case), 5.0, True)
        if method == sr.EMCEE:
            run.sampler, run.tau_max, run.n_steps = "emcee", 6.0, 200
        elif method == "bayes":
            run.sampler, run.pareto_k = "importance", 0.3
        if method != "map":
            run.ess = {n: 1000.0 + 10 * i for i, n in enumerate(PARAMETER_UNITS)}
            # the slow record's b₁ 0.15 sd apart between the paths (beyond 0.1 sd); τ's sd 12 %
            # apart everywhere (within the 15 % of the uncertified)
            off = 0.15 if (case == "slow" and method == "bayes") else 0.0
            run.moments = {"b1": (7.0 + off * 0.01, 0.01), "tau_s": (40.0, 1.0)}
            if method == "bayes":
                run.moments["tau_s"] = (40.05, 1.12)
        return run

    monkeypatch.setattr(sr, "write_records", lambda d, s, q: {c: d / c for c in sr.CASES})
    written = []
    monkeypatch.setattr(sr, "write_archive_records", lambda d, s, q, n: written.append(n))
    monkeypatch.setattr(sr, "timed_calibrate", fake_calibrate)
    monkeypatch.setattr(
        sr,
        "timed_reanalyze",
        lambda *a: {"seconds": 8.0, "sessions": 4, "result_seconds": [3, 4, 5, 6], "jobs": 2},
    )
    rows = sr.run(quick=True)
    _check_several_records_rows(rows)
    bare = np.median([0.5 + 0.1 * len(c) for c in sr.CASES for _ in range(2)])
    (summ,) = [r for r in rows if r.label.startswith("`calibrate --method bayes` over")]
    assert summ.values["worst_case"] == "slow"
    assert summ.values["worst_ratio_to_bare"] == pytest.approx(30.0 / bare)
    assert summ.values["median_seconds"] == 13.0
    assert summ.values["target_met"] is False  # 30 s is beyond 6× a ~1 s start
    agreement = {
        r.values["case"]: r
        for r in rows
        if r.label.endswith(tuple("vs emcee, " + c for c in sr.CASES))
    }
    assert sorted(agreement) == sorted(sr.CASES)
    assert [c for c, r in agreement.items() if not r.values["agree"]] == ["slow"]
    assert agreement["slow"].note.startswith("DISAGREE")
    assert agreement["slow"].values["certified_dmean_over_sd"] == pytest.approx(0.15)
    assert agreement["typical"].values["other_dsd"] == pytest.approx(0.12)
    assert agreement["typical"].values["other_dmean_over_sd"] == pytest.approx(0.05)
    (re,) = [r for r in rows if r.label.startswith("`reanalyze --method bayes` over the 4")]
    assert re.values["sessions_per_s"] == 0.5
    assert re.values["warm_sessions_per_s_estimate"] == 2 / 4.5
    # the rate: many paper-program records (3 h with quick), one more reanalyze
    (many,) = [r for r in rows if r.label.startswith("`reanalyze --method bayes` over 16 3 h")]
    assert written == [16] and many.values["sessions_per_s"] == 0.5

    def failing(case, rec, method, tmp, env):
        if case == "slow" and method == "bayes":
            raise RuntimeError("chekan calibrate slow.csv exited 1: ValueError: boom")
        return fake_calibrate(case, rec, method, tmp, env)

    monkeypatch.setattr(sr, "timed_calibrate", failing)
    rows = sr.run(quick=True)
    _check_several_records_rows(rows)
    (bad,) = [r for r in rows if r.figure == "FAILED"]
    assert bad.label.startswith("`calibrate --method bayes`, slow") and "boom" in bad.note
    (summ,) = [r for r in rows if r.label.startswith("`calibrate --method bayes` over 3")]
    assert summ.values["worst_case"] == "misaligned" and summ.values["median_seconds"] == 12.0


@pytest.mark.slow
@pytest.mark.skipif(
    not __import__("os").environ.get("CHEKAN_TEST_BENCH_BAYES"),
    reason="four new map processes each compile a record shape: minutes on 2 cores "
    "(set CHEKAN_TEST_BENCH_BAYES=1); the stubbed test covers the table",
)
def test_several_records_quick_map_runs_the_new_processes():
    """``--quick --skip-bayes`` for real: four short records through new ``calibrate --method
    map`` processes beside bare JAX starts; the rows exist and hold finite numbers (their
    speed is not asserted)."""
    from bench.several_records import run

    _check_several_records_rows(run(seed=0, quick=True, skip_bayes=True), methods=("map",))


@pytest.mark.slow
@pytest.mark.skipif(
    not __import__("os").environ.get("CHEKAN_TEST_BENCH_BAYES"),
    reason="four bayes processes and a reanalyze take minutes on 2 cores "
    "(set CHEKAN_TEST_BENCH_BAYES=1)",
)
def test_several_records_quick_runs_bayes_and_reanalyze():
    """``--quick`` for real, bayes and ``reanalyze --method bayes`` included."""
    from bench.several_records import run

    _check_several_records_rows(run(seed=0, quick=True))
