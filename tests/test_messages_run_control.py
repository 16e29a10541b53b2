"""Issue 57 §4: messages and run control. A bad ``--at`` date is a usage error; warnings are
one line each, in words; a settling time longer than every hold says so; the live page
knows an acquisition killed with -9 (no RUNNING, no "link stalled", no line across the gap,
no "all healthy" after the resume); Ctrl-C of the reanalyze parent ends it at once; the
certificate's computing time and |mean δg| say what they are; bayes checks the room for
its posterior before any work."""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from chekan.cli.commands import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("at", ["2027-13-45", "banana", "2027-02-30"])
def test_history_at_a_date_that_is_none_is_a_usage_error(at, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["history", "46", "--db", str(tmp_path / "a.sqlite"), "--at", at])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert f"--at: '{at}' is not a date written YYYY-MM-DD" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def _stderr_lines(err: str) -> list[str]:
    lines = err.strip().splitlines()
    for line in lines:
        assert line.startswith("chekan: "), err
        assert not re.search(r"\.py:\d+|UserWarning|Traceback", line), err
    return lines


def _chekan(*args: str) -> subprocess.CompletedProcess:
    """``chekan ARGS`` in its own process: its warnings as a user sees them (pytest would
    catch them in this one)."""
    return subprocess.run(
        [sys.executable, "-m", "chekan.cli", *args],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=300,
    )


def test_a_settling_time_longer_than_every_hold_is_one_warning_and_a_clear_error(short_session):
    path = short_session[0]  # holds of 300 s
    p = _chekan("calibrate", str(path), "-q", "--settle-s", "900")
    assert p.returncode == 2
    lines = _stderr_lines(p.stderr)
    assert len(lines) == 2, lines
    assert lines[0].startswith("chekan: warning: ") and "holds (steps 0–" in lines[0]
    assert "no complete ± pair" not in lines[1]
    assert "(900 s) is not shorter than any hold" in lines[1] and "--settle-s" in lines[1]


def test_a_truncated_records_warning_is_one_line_in_words(short_session, tmp_path):
    cut = tmp_path / "cut.csv"
    cut.write_bytes(short_session[0].read_bytes()[:-25])
    p = _chekan("calibrate", str(cut), "-q")
    assert p.returncode == 0, p.stderr
    lines = _stderr_lines(p.stderr)
    assert len(lines) == 1 and "incomplete last line skipped" in lines[0], lines
    assert lines[0].startswith(f"chekan: warning: {cut}:")


# ---------------------------------------------------------------------- the live page
def _live_record(short_session, tmp_path: Path, n: int) -> Path:
    """The first ``n`` rows of the short session, with a journal that started the run and
    never stopped it."""
    text = short_session[0].read_text().splitlines(keepends=True)
    header = next(i for i, ln in enumerate(text) if ln.startswith("t_s"))
    rows = text[header + 1 : header + 1 + n]
    rec = tmp_path / "rec.csv"
    rec.write_text("".join(text[: header + 1] + rows))
    ev = {"event": "run_start", "utc": "2026-11-25T08:00:00Z", "plan": [], "rate_hz": 1.0}
    Path(f"{rec}.journal.jsonl").write_text(json.dumps(ev) + "\n", encoding="utf-8")
    return rec


class _Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_the_live_page_knows_an_acquisition_killed_with_9(short_session, tmp_path):
    from chekan.live import calib
    from chekan.live.state import GONE, LiveState

    if not Path("/proc/locks").is_file():
        pytest.skip("no /proc/locks: the page cannot tell a killed acquisition")
    rec = _live_record(short_session, tmp_path, 600)
    journal = open(f"{rec}.journal.jsonl", "ab")  # the acquisition holds its journal's lock
    fcntl.flock(journal.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    clock = _Clock()
    st = LiveState(rec, map_runner=calib.MapRunner(), clock=clock)
    st.update()
    clock.t += 60  # a real stall: the acquisition still runs
    s = st.status()
    assert s["state"] == "running" and any("link stalled" in a["text"] for a in s["alarms"])
    journal.close()  # kill -9: the kernel drops its lock, nothing journalled
    s = st.status()
    assert s["state"] == GONE and s["remaining_s"] is None, s["state"]
    texts = [a["text"] for a in s["alarms"]]
    assert not any("link stalled" in t for t in texts), texts
    assert any("without journalling an end" in t and "--resume" in t for t in texts), texts
    # resumed: the page says the run was interrupted, never "all healthy"
    journal = open(f"{rec}.journal.jsonl", "ab")
    fcntl.flock(journal.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    journal.write(b'{"event": "resume", "utc": "2026-11-25T08:20:00Z", "t_s": 700.0}\n')
    journal.flush()
    src = short_session[0].read_text().splitlines(keepends=True)
    header = next(i for i, ln in enumerate(src) if ln.startswith("t_s"))
    with open(rec, "a") as f:
        f.write("".join(src[header + 1 + 700 : header + 1 + 900]))
    st.update()
    s = st.status()
    journal.close()
    assert s["state"] == "running" and s["health"]["interruptions"] == 1
    assert s["health"]["gaps"] == 1 and s["health"]["lost_samples"] == 100
    assert any("interrupted without an end 1 time(s)" in a["text"] for a in s["alarms"])


def test_the_live_plot_is_not_joined_across_a_gap():
    node = shutil.which("node")
    if node is None:
        pytest.skip("no node to run the page's script")
    page = (ROOT / "chekan" / "live" / "static" / "page.html").read_text(encoding="utf-8")
    fn = page[page.index("function breakGaps") : page.index("// end breakGaps")]
    th = [t / 3600 for t in (0, 1, 2, 103, 104)]  # 100 samples lost after t = 2 s
    js = fn + f"console.log(JSON.stringify(breakGaps({th}, [[1, 2, 3, 4, 5]], 1)));"
    out = json.loads(subprocess.run([node, "-e", js], capture_output=True, text=True).stdout)
    x, y = out
    assert y == [1, 2, 3, None, 4, 5]
    assert x[2] < x[3] < x[4] and len(x) == 6


# ---------------------------------------------------------------------- reanalyze
def test_ctrl_c_of_the_reanalyze_parent_alone_ends_it_at_once(tmp_path):
    """A worker busy for two minutes (a MAP compiling): SIGINT to the parent alone ends the
    parent and its workers within seconds (its executor's shutdown waited for the task)."""
    script = tmp_path / "batch.py"
    script.write_text(
        "import os, time\n"
        "from chekan.archive.reanalyze import make_executor\n"
        "if __name__ == '__main__':\n"
        "    with make_executor('local', 1) as ex:\n"
        "        ex.submit(os.getpid).result()\n"
        "        busy = ex.submit(time.sleep, 120)\n"
        "        print('busy', flush=True)\n"
        "        busy.result()\n",
        encoding="utf-8",
    )
    p = subprocess.Popen(
        [sys.executable, str(script)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        assert p.stdout is not None and p.stdout.readline().strip() == "busy"
        time.sleep(0.5)
        t0 = time.monotonic()
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=30)
        assert time.monotonic() - t0 < 15
        assert "KeyboardInterrupt" in err
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()


# ---------------------------------------------------------------------- the certificate
def test_the_certificates_time_and_largest_mean_dg_say_what_they_are(tmp_path, capsys):
    res = json.loads((ROOT / "tests/data/report/bayes_result.json").read_text(encoding="utf-8"))
    res["method"] = "map"
    res["residuals_mgal"]["mean_delta_g_mgal"][2] = -0.57  # the largest in size, negative
    src = tmp_path / "map.json"
    src.write_text(json.dumps(res), encoding="utf-8")
    out = tmp_path / "c.html"
    assert main(["report", str(src), "-q", "-o", str(out)]) == 0, capsys.readouterr().err
    html = out.read_text(encoding="utf-8")
    assert "Sampling time" not in html and "Computing time (compiling included)" in html
    assert "largest |mean δg| = 0.57 mGal" in html, re.findall(r"largest[^<]*", html)


# ---------------------------------------------------------------------- bayes, full disk
def test_bayes_checks_the_room_for_its_posterior_before_any_work(
    short_session, tmp_path, monkeypatch, capsys
):
    import importlib

    import chekan.files.outputs as outputs

    estimate = importlib.import_module("chekan.fit.record")  # chekan.fit.record: a function

    def no_work(*args, **kwargs):
        raise AssertionError("the MAP ran before the room was checked")

    monkeypatch.setattr(estimate, "fit_map_em", no_work)
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(outputs.shutil, "disk_usage", lambda p: usage._replace(free=50_000))
    out = tmp_path / "r.json"
    assert (
        main(["calibrate", str(short_session[0]), "--method", "bayes", "-q", "-o", str(out)]) == 1
    )
    err = capsys.readouterr().err
    assert f"{tmp_path / 'r.nc'}: no room for the posterior NetCDF" in err, err
    assert "Traceback" not in err and not out.exists()
