"""The live page (chekan.live): file followers, running calibration, crash isolation, browser."""

from __future__ import annotations

import itertools
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from children import interrupt

from chekan.live import calib
from chekan.live.follow import JournalFollower, RawLogFollower, RecordFollower
from chekan.live.state import LiveState

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
HEADER = "# format: chekan-record/1\n# serial: 46\n# g_local_mgal: 981922.05\n"
COLS = "t_s,m1_pix,m2_pix,tilt_x_arcsec,tilt_y_arcsec,step,temp_c\n"
SHORT_TOML = """name = "live-e2e"
angles = ["3°10'", "5°10'"]
axis = "y"
dwell_s = 90
settle_s = 45
rounds = 2
"""


# ----------------------------------------------------------------------------- followers


def test_record_follower_torn_line_and_growing_file(tmp_path):
    p = tmp_path / "rec.csv"
    f = RecordFollower(p)
    assert f.poll() is None  # not there yet
    p.write_text(HEADER + COLS + "0,1000.5,990.25,0.1,-0.2,0,45.0\n1,1000.6,9")  # torn
    rows = f.poll()
    assert rows["t_s"].tolist() == [0.0]
    assert f.meta["serial"] == "46" and f.pending == b"1,1000.6,9"
    assert f.poll() is None  # nothing new: the torn line stays aside
    with open(p, "a") as fh:
        fh.write("90.5,0.1,-0.2,,45.0\n2,1000.7,990.7,0.1,-0.2,1,\n")
    rows = f.poll()
    assert rows["t_s"].tolist() == [1.0, 2.0]
    assert rows["m2_pix"][0] == pytest.approx(990.5)
    assert np.isnan(rows["step"][0]) and rows["step"][1] == 1 and np.isnan(rows["temp_c"][1])
    with open(p, "a") as fh:
        fh.write("3,1,2,3\n4,x,1,1,1,1,1\n5,1,1,1,1,1,1\n")  # two malformed rows are skipped
    assert f.poll()["t_s"].tolist() == [5.0] and f.bad_rows == 2
    p.write_text(HEADER + COLS + "0,1,1,1,1,0,1\n")  # replaced by a shorter file
    assert "reset" in f.poll()
    assert f.poll()["t_s"].tolist() == [0.0]


def test_record_follower_columns_in_any_order_without_temp(tmp_path):
    p = tmp_path / "rec.csv"
    p.write_text(HEADER + "step,t_s,m2_pix,m1_pix,tilt_y_arcsec,tilt_x_arcsec\n3,7,2,1,5,4\n")
    rows = RecordFollower(p).poll()
    assert [rows[c][0] for c in ("t_s", "m1_pix", "m2_pix", "tilt_x_arcsec", "step")] == [
        7,
        1,
        2,
        4,
        3,
    ]
    assert np.isnan(rows["temp_c"][0])


def test_journal_and_raw_log_followers(tmp_path):
    j = tmp_path / "rec.csv.journal.jsonl"
    j.write_text('{"event": "run_start", "utc": "x"}\n{"event": "ste')
    f = JournalFollower(j)
    assert [e["event"] for e in f.poll()] == ["run_start"]
    with open(j, "a") as fh:
        fh.write('p_done", "step": 0}\n')
    assert f.poll() == [{"event": "step_done", "step": 0}]

    from hw.nmea import encode

    good = encode("GRV", 1, "1000.1", "990.2", "45.0", "OK").decode().strip()
    raw = tmp_path / "rec.csv.raw.log"
    raw.write_text(
        f"sensor< {good}\nsensor< $GRV,2,1,2,45,OK*00\nsensor< noise\\x01\n"
        "platform> $PLQ,LEVEL*5A\nplatform< $PLT,1,0,0,HOLD*00\n"
    )
    r = RawLogFollower(raw)
    assert r.poll()
    d = r.dropped()
    assert d["sensor"]["bad_checksum"] == 1 and d["platform"]["bad_checksum"] == 1
    assert d["sensor"].get("garbage_bytes", 0) > 0


# ----------------------------------------------------------------------------- calibration


class _FakeRunner(calib.MapRunner):
    def __init__(self):
        super().__init__()
        self.submitted: list[tuple[int, int]] = []

    def submit(self, round_no, record):
        self.submitted.append((round_no, record.n))


def _write_in_chunks(src: bytes, dst: Path, state: LiveState, n_chunks: int):
    """Grow ``dst`` from ``src`` in pieces cut anywhere (torn lines included)."""
    cuts = np.linspace(0, len(src), n_chunks + 1).astype(int)
    snaps = []
    for a, b in itertools.pairwise(cuts):
        with open(dst, "ab") as fh:
            fh.write(src[a:b])
        state.update()
        snaps.append(state.classical)
    return snaps


def test_running_classical_converges_and_map_is_asked_per_round(short_session, tmp_path):
    path, rec, _ = short_session
    dst = tmp_path / "growing.csv"
    runner = _FakeRunner()
    st = LiveState(dst, map_runner=runner)
    snaps = _write_in_chunks(path.read_bytes(), dst, st, 60)
    assert st.n == rec.n
    pairs = [s["pairs"] for s in snaps if s]
    assert pairs[0] >= 1 and pairs == sorted(pairs)  # one more pair at a time, never fewer
    final = snaps[-1]
    assert final["pairs"] == 16 and final["rounds_complete"] == 2
    # the last snapshot is the classical method on the whole record
    from chekan.classical.fit import calibrate_record
    from chekan.records import read_record

    cres, _ = calibrate_record(read_record(path))
    np.testing.assert_allclose(final["b_mean"], cres.b_mean, rtol=1e-12)
    assert final["a"] == pytest.approx(cres.a)
    assert np.array(final["delta_g_mgal"]).shape == (2, 2, 8)
    # one MAP per completed round, on the rows up to that round's closing level hold
    assert [r for r, _ in runner.submitted] == [1, 2]
    assert runner.submitted[0][1] < runner.submitted[1][1] <= rec.n
    s = st.status()
    assert s["state"] == "record (no journal)" and s["holds"] and not s["alarms"]


def test_partial_record_keeps_only_completed_steps(short_session):
    _, rec, _ = short_session
    cols = {c: getattr(rec, c) for c in ("t_s", "m1_pix", "m2_pix", "tilt_x_arcsec")}
    cols |= {"tilt_y_arcsec": rec.tilt_y_arcsec, "step": rec.step.astype(float), "temp_c": None}
    part = calib.partial_record(rec.meta, cols, {0, 1, 2})
    assert set(np.unique(part.step)) == {-1, 0, 1, 2}
    assert calib.classical_snapshot(part)["pairs"] == 1
    assert calib.classical_snapshot(calib.partial_record(rec.meta, cols, {0, 1})) is None


def test_expected_sd_from_the_journal_plan_matches_chekan_design(short_program):
    from chekan.design import expected_precision
    from hw.acquisition import plan_from_program

    plan = [vars(s) for s in plan_from_program(short_program)]
    prog = calib.program_from_plan(plan)
    assert prog.axis == short_program.axis and len(prog.angles_rad) == 8
    got = calib.expected_sd(prog)
    want = expected_precision(short_program).sd
    for k in ("b1", "b2", "a"):
        assert got[k] == pytest.approx(want[k], rel=1e-3)  # the plan's angles are arcsec


def test_map_runner_reports_a_failing_job_and_goes_on():
    r = calib.MapRunner(job=_boom)
    try:
        r.submit(1, None)
        deadline = time.monotonic() + 60
        while not r.poll() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert r.errors and "boom 1" in r.errors[0] and r.busy_round is None
    finally:
        r.close()


def _boom(record, round_no):  # module level: the worker process imports it
    raise RuntimeError(f"boom {round_no}")


_ORPHAN = """
import sys, time
sys.path.insert(0, sys.argv[1])
from chekan.live import calib
r = calib.MapRunner(job=time.sleep)  # a "MAP" that takes 10 minutes
r.submit(600, None)
time.sleep(0.5)
print(*r._pool._processes, flush=True)  # the worker's pid
time.sleep(600)
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"  # a zombie has ended
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
def test_the_map_worker_ends_when_the_page_is_killed_mid_job():
    page = subprocess.Popen(
        [sys.executable, "-c", _ORPHAN, str(ROOT)], stdout=subprocess.PIPE, text=True
    )
    try:
        worker = int(page.stdout.readline())
        assert _alive(worker)
        page.kill()  # SIGKILL: no chance to shut the pool down
        page.wait(10)
        deadline = time.monotonic() + 15
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(worker), "the MAP worker outlived its page"
    finally:
        page.kill()


def test_update_errors_do_not_stop_the_page(tmp_path):
    from chekan.live.server import LiveServer

    st = LiveState(tmp_path / "rec.csv", map_runner=_FakeRunner())
    calls = []

    def broken():
        calls.append(1)
        raise ValueError("injected")

    st.update = broken
    srv = LiveServer(("127.0.0.1", 0), st)
    import threading

    threading.Thread(target=srv.serve_forever, daemon=True).start()
    t = threading.Thread(target=srv.follow, kwargs={"poll_s": 0.01}, daemon=True)
    t.start()
    time.sleep(0.3)
    try:
        assert len(calls) > 3 and t.is_alive()
        with urllib.request.urlopen(srv.url + "api/status", timeout=5) as resp:
            assert json.load(resp)["state"] == "waiting for the record"
        with urllib.request.urlopen(srv.url, timeout=5) as resp:
            assert b"uPlot" in resp.read()
    finally:
        srv.stop()
        srv.server_close()


def test_bad_live_address_is_refused():
    from chekan.errors import ChekanError
    from chekan.live.server import parse_address

    assert parse_address("0") == ("127.0.0.1", 0)
    assert parse_address("0.0.0.0:8050") == ("0.0.0.0", 8050)
    for bad in ("x", "1:99999"):
        with pytest.raises(ChekanError):
            parse_address(bad)


# ----------------------------------------------------------------------------- end to end

_HW = "import sys; from hw.cli import main; sys.exit(main(sys.argv[1:]))"


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


class _Run:
    """Emulator and ``acquire --live 127.0.0.1:0`` as subprocesses."""

    def __init__(self, tmp: Path, speed: float, *extra: str):
        self.tmp = tmp
        (tmp / "prog.toml").write_text(SHORT_TOML, encoding="utf-8")
        self.rec = tmp / "rec.csv"
        sensor, platform = tmp / "sensor", tmp / "platform"
        self.emu = subprocess.Popen(
            [
                *(sys.executable, "-c", _HW, "emulate", "--sensor", str(sensor), "--platform"),
                *(str(platform), "--speed", str(speed), "--seed", "4", "--duration-s", "400"),
            ],
            cwd=ROOT,
            env=_env(),
            stdout=subprocess.PIPE,
            text=True,
        )
        self.emu.stdout.readline()  # the emulator's first line: its ports exist
        self.acq = subprocess.Popen(
            [
                *(sys.executable, "-c", _HW, "acquire", "--sensor", str(sensor), "--platform"),
                *(str(platform), "--out", str(self.rec), "--program", str(tmp / "prog.toml")),
                *("--g-local-mgal", "981922.05", "--quiet", "--live", "127.0.0.1:0", *extra),
            ],
            cwd=ROOT,
            env=_env(),
            stdout=subprocess.PIPE,
            text=True,
        )
        self.lines: list[str] = []
        self.url = self.live_pid = None
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = self.acq.stdout.readline()
            if not line:
                break
            self.lines.append(line)
            m = re.match(r"live page (\S+) \(pid (\d+)", line)
            if m:
                self.url, self.live_pid = m[1], int(m[2])
                break
        assert self.url, f"no live page line in {self.lines}"

    def finish(self, timeout_s: float = 240) -> tuple[int, str]:
        out, _ = self.acq.communicate(timeout=timeout_s)
        return self.acq.returncode, "".join(self.lines) + out

    def close(self) -> None:
        for p in (self.acq, self.emu):
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
        if self.live_pid is not None:
            try:
                os.kill(self.live_pid, signal.SIGTERM)
            except ProcessLookupError:
                pass


def _check_complete(rec: Path, n_steps: int = 12):
    from chekan.records import read_record
    from hw.journal import read_journal

    r = read_record(rec)
    assert set(np.unique(r.step[r.step >= 0])) == set(range(n_steps))
    stop = [e for e in read_journal(f"{rec}.journal.jsonl") if e["event"] == "run_stop"]
    assert stop and stop[-1]["status"] == "completed" and stop[-1]["exit_code"] == 0


@pytest.mark.slow
def test_killing_the_live_page_never_stops_the_acquisition(tmp_path):
    run = _Run(tmp_path, speed=100)
    try:
        with urllib.request.urlopen(run.url + "api/status", timeout=10) as resp:
            assert json.load(resp)["pid"] == run.live_pid
        os.kill(run.live_pid, signal.SIGKILL)  # the page crashes mid-run
        code, out = run.finish()
        assert code == 0, out
        assert "acquisition completed (exit 0)" in out
        _check_complete(run.rec)
    finally:
        run.close()


def _screenshot_dirs(tmp_path: Path) -> list[Path]:
    dirs = [tmp_path]
    if os.environ.get("CHEKAN_ARTEFACTS"):
        d = Path(os.environ["CHEKAN_ARTEFACTS"])
        d.mkdir(parents=True, exist_ok=True)
        dirs.append(d)
    return dirs


CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@pytest.mark.slow
@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} absent (make browser)")
@pytest.mark.timeout(300)
def test_live_page_in_a_browser_end_to_end(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api")
    run = _Run(tmp_path, speed=25)
    profile = tempfile.mkdtemp(prefix="chekan-chromium-")
    try:
        with sync_api.sync_playwright() as pw:
            ctx = pw.chromium.launch_persistent_context(
                profile,
                executable_path=CHROMIUM,
                args=CHROMIUM_ARGS,
                headless=True,
                viewport={"width": 1500, "height": 1000},
            )
            page = ctx.new_page()
            page.goto(run.url)
            page.wait_for_function("Number(document.body.dataset.points || 0) > 5", timeout=60_000)
            first = int(page.evaluate("document.body.dataset.step || '0'"))
            page.wait_for_function(
                f"Number(document.body.dataset.step || -1) > {first}", timeout=90_000
            )
            assert page.locator("#step-counter").inner_text().endswith("/ 12")
            # a running b after the first round (MAP in the page's worker process)
            page.wait_for_function(
                "Number(document.body.dataset.mapRounds || 0) >= 1", timeout=200_000
            )
            b1 = page.locator(".map-b1").first.inner_text()
            assert re.match(r"\d+\.\d+ ± \d+\.\d+", b1), b1
            # 45 s settling at the emulator's τ: the classical preview says it is biased
            unsettled = page.locator("#cl-unsettled")
            assert unsettled.is_visible() and "slews' transients" in unsettled.inner_text()
            assert int(page.evaluate("document.body.dataset.points")) > 100
            # issue 33 §5: the readings as numbers, the wall-clock end, each hold's axis
            for rid in ("#r-m1", "#r-m2", "#r-tx", "#r-ty", "#r-temp"):
                assert re.fullmatch(r"-?\d+\.\d+", page.locator(rid).inner_text()), rid
            assert re.match(r"\d\d:\d\d", page.locator("#end").inner_text())
            axes = page.locator("#holds tr.hold-row td:nth-child(4)").all_inner_texts()
            assert axes and set(axes) == {"Y"}
            assert "about Y" in page.locator("#step-label").inner_text() or (
                page.locator("#step-label").inner_text().startswith("level")
            )
            page.wait_for_timeout(500)
            for d in _screenshot_dirs(tmp_path):
                page.screenshot(path=str(d / "live_page.png"), full_page=True)
            page.set_viewport_size({"width": 1024, "height": 768})  # alarms above the fold
            page.wait_for_timeout(300)
            box = page.locator("#alarms").bounding_box()
            assert box is not None and box["y"] + box["height"] <= 768, box
            ctx.close()
        code, out = run.finish()
        assert code == 0, out
        _check_complete(run.rec)
        assert (tmp_path / "live_page.png").stat().st_size > 10_000
    finally:
        run.close()
        shutil.rmtree(profile, ignore_errors=True)


def test_client_mistakes_get_an_answer_not_a_traceback(tmp_path, capfd):
    """``/api/rows?from=abc`` is a 400; a client that disconnects mid-request prints
    nothing (issue 33 §4)."""
    import socket
    import threading
    import urllib.error

    from chekan.live.server import LiveServer

    srv = LiveServer(("127.0.0.1", 0), LiveState(tmp_path / "rec.csv", map_runner=_FakeRunner()))
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        for bad in ("abc", "-1", "1.5", "1e3"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(srv.url + f"api/rows?from={bad}", timeout=5)
            assert e.value.code == 400 and b"row number" in e.value.read()
        with urllib.request.urlopen(srv.url + "api/rows?from=0", timeout=5) as resp:
            assert resp.status == 200
        host, port = srv.server_address[:2]
        for _ in range(5):  # half a request, then a reset (SO_LINGER 0)
            s = socket.create_connection((host, port))
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
            s.sendall(b"GET /api/status HTTP/1.1\r\nHost: x\r\n")
            s.close()
        time.sleep(0.5)
    finally:
        srv.stop()
        srv.server_close()
    err = capfd.readouterr().err
    assert "Traceback" not in err and "ConnectionResetError" not in err, err


def test_an_all_interfaces_bind_is_announced_with_a_warning(tmp_path):
    from chekan.live.server import LiveServer

    srv = LiveServer(("0.0.0.0", 0), LiveState(tmp_path / "rec.csv", map_runner=_FakeRunner()))
    try:
        assert srv.open_to_network and srv.bound.startswith("0.0.0.0:")
        assert srv.url.startswith("http://127.0.0.1:")
    finally:
        srv.server_close()


# ----------------------------------------------------------------------------- issue 33 §5


class _Capture(calib.MapRunner):
    """A runner that keeps the records it is given (the estimators' input)."""

    def __init__(self):
        super().__init__()
        self.records = []

    def submit(self, round_no, record):
        self.records.append(record)


def _quiet_state(path: Path, runner=None) -> LiveState:
    """The state of a file that no longer grows (a finished record), alarms included."""
    now = [0.0]
    st = LiveState(path, map_runner=runner or _FakeRunner(), clock=lambda: now[0], stall_s=5.0)
    st.update()
    now[0] = 10.0
    st.update()
    return st


def test_a_binary_file_raises_an_alarm_not_all_healthy(tmp_path):
    p = tmp_path / "scope.bin"
    p.write_bytes(bytes(range(256)) * 40)
    s = _quiet_state(p).status()
    assert s["state"] == "not a record" and s["n"] == 0
    assert [a["level"] for a in s["alarms"]] == ["alarm"]
    assert s["alarms"][0]["text"].startswith(f"{p}: ") and "format" in s["alarms"][0]["text"]
    p2 = tmp_path / "noise.bin"
    p2.write_bytes(b"\x01\x02" * 40_000)  # no line end at all
    (a,) = _quiet_state(p2).status()["alarms"]
    assert a["text"].startswith(f"{p2}: no line end") and a["level"] == "alarm"


def test_a_record_running_backwards_is_named_with_its_line_and_not_calibrated(
    short_session, tmp_path
):
    path, rec, _ = short_session
    lines = path.read_bytes().split(b"\n")
    header = next(i for i, ln in enumerate(lines) if ln.startswith(b"t_s"))
    k = header + 1 + 3000  # the 3001st row goes back 100 s, and the rows after it
    for i in range(k, len(lines) - 1):
        f = lines[i].split(b",")
        f[0] = str(float(f[0]) - 100).encode()
        lines[i] = b",".join(f)
    back = tmp_path / "mine.csv"
    back.write_bytes(b"\n".join(lines))
    runner = _Capture()
    st = _quiet_state(back, runner)
    s = st.status()
    from chekan.errors import FormatError
    from chekan.records import read_record

    with pytest.raises(FormatError) as e:  # the page says what chekan calibrate would
        read_record(back)
    assert str(e.value).startswith(f"{back}:{k + 1}: t_s goes backwards")
    assert {"level": "alarm", "text": str(e.value)} in s["alarms"]
    assert st.classical is None and runner.records == []  # no numbers from a broken record
    assert s["n"] == rec.n  # the plot still shows every row


def test_a_finished_record_speaks_of_the_users_file(short_session, tmp_path):
    """A record that ends without its closing level step: the classical note and every
    record handed to the estimators name the user's file, never a temporary one."""
    path, rec, _ = short_session
    last_tilt = int(rec.step.max()) - 1  # drop the final level step
    lines = path.read_text().splitlines(keepends=True)
    header = next(i for i, ln in enumerate(lines) if ln.startswith("t_s"))
    keep = [ln for ln in lines[header + 1 :] if int(ln.split(",")[5] or -1) <= last_tilt]
    mine = tmp_path / "session 12.csv"
    mine.write_text("".join(lines[: header + 1] + keep))
    runner = _Capture()
    st = _quiet_state(mine, runner)
    texts = [a["text"] for a in st.status()["alarms"]]
    assert (
        f"{mine}: round 2: no level step after it; drift between level steps cannot be removed"
        in texts
    )
    assert runner.records and {r.path for r in runner.records} == {str(mine)}
    assert not any(
        "partial" in t or "<live>" in t or "tmp" in t.replace(str(tmp_path), "") for t in texts
    )


def _journal(path: Path, events: list[dict]) -> None:
    Path(f"{path}.journal.jsonl").write_text(
        "".join(json.dumps(e) + "\n" for e in events), encoding="utf-8"
    )


def _plan(short_program) -> list[dict]:
    from hw.acquisition import plan_from_program

    return [vars(s) for s in plan_from_program(short_program)]


def test_readings_end_time_and_the_error_state(short_session, short_program, tmp_path):
    from datetime import UTC, datetime, timedelta

    path, rec, _ = short_session
    mine = tmp_path / "rec.csv"
    n = 2000
    text = path.read_text().splitlines(keepends=True)
    header = next(i for i, ln in enumerate(text) if ln.startswith("t_s"))
    mine.write_text("".join(text[: header + 1 + n]))
    t0 = datetime(2026, 11, 25, 8, 0, tzinfo=UTC)

    def stamp(t_s: float, pace: float = 2.0) -> str:  # the wall clock runs at half speed
        return (t0 + timedelta(seconds=t_s * pace)).strftime("%Y-%m-%dT%H:%M:%S.%fZ")

    plan = _plan(short_program)
    events = [
        {"event": "run_start", "utc": stamp(0), "plan": plan, "rate_hz": 1.0, "program": "p"},
        {"event": "step_start", "utc": stamp(0), "step": 0, "round": 1, "kind": "level",
         "label": "level", "dwell_samples": 300, "t_s": 0.0},
        {"event": "hold", "utc": stamp(0), "step": 0, "t_s": 0.0},
        {"event": "step_done", "utc": stamp(float(rec.t_s[n - 1])), "step": 0,
         "t_s": float(rec.t_s[n - 1])},
    ]  # fmt: skip
    _journal(mine, events)
    st = LiveState(mine, map_runner=_FakeRunner())
    st.update()
    s = st.status()
    from chekan.records import read_record

    mine_rec = read_record(mine)  # the numbers as the file holds them
    for c in ("m1_pix", "m2_pix", "tilt_x_arcsec", "tilt_y_arcsec", "temp_c"):
        assert s["readings"][c] == float(getattr(mine_rec, c)[-1]), c
    left = s["remaining_s"]
    assert left > 0 and s["end"]["estimated"] and s["stopped"] is None
    end = datetime.fromisoformat(s["end"]["utc"].replace("Z", "+00:00"))
    want = datetime.now(UTC) + timedelta(seconds=2.0 * left)  # at the journal's pace
    assert abs((end - want).total_seconds()) < 5
    # the platform refused a TILT: the run stopped with exit 1
    stop = stamp(float(rec.t_s[n - 1]) + 5)
    with open(f"{mine}.journal.jsonl", "a") as f:
        msg = "platform: TILT refused: RANGE"
        ev = {"event": "run_stop", "utc": stop, "status": "device_error", "exit_code": 1}
        f.write(json.dumps({**ev, "message": msg}) + "\n")
    st.update()
    s = st.status()
    assert s["state"] == "device_error" and s["remaining_s"] is None
    assert s["stopped"] == {
        "status": "device_error",
        "exit_code": 1,
        "message": "platform: TILT refused: RANGE",
    }
    assert s["end"] == {"utc": stop[:19] + "Z", "estimated": False}
    assert any("TILT refused" in a["text"] for a in s["alarms"])


def _about_x_in_round_2(rec, path: Path, out: Path) -> None:
    """The short session with its second round's tilts about X (tilt columns swapped)."""
    from chekan.records import write_record
    from chekan.records.holds import segment_record

    holds = segment_record(rec, settle_s=200)
    r2 = holds.rounds[1]
    steps = {int(holds.step[i]) for i in r2.tilt_holds}
    sel = np.isin(rec.step, sorted(steps))
    tx, ty = rec.tilt_x_arcsec.copy(), rec.tilt_y_arcsec.copy()
    tx[sel], ty[sel] = rec.tilt_y_arcsec[sel], rec.tilt_x_arcsec[sel]
    import dataclasses

    write_record(out, dataclasses.replace(rec, tilt_x_arcsec=tx, tilt_y_arcsec=ty))


def test_the_axis_of_each_hold_from_the_record_and_from_the_plan(short_session, tmp_path):
    from chekan.records import read_record
    from chekan.records.holds import segment_record

    path, rec, _ = short_session
    xy = tmp_path / "xy.csv"
    _about_x_in_round_2(rec, path, xy)
    want = segment_record(read_record(xy), settle_s=200)
    assert want.axis == "xy"
    s = _quiet_state(xy).status()
    axes = {h[2]: h[3] for h in s["holds"]}
    assert axes == dict(zip(want.step.tolist(), want.hold_axis.tolist(), strict=True))
    assert set(axes.values()) == {"x", "y"}
    # with a journal the plan gives the axis at once (before a hold completes)
    from chekan.live.state import _plan_axes

    plan = [
        {"index": 0, "kind": "level", "x_arcsec": 0.0, "y_arcsec": 0.0},
        {"index": 1, "kind": "tilt", "x_arcsec": 0.0, "y_arcsec": 3600.0},
        {"index": 2, "kind": "level", "x_arcsec": 0.0, "y_arcsec": 0.0},
        {"index": 3, "kind": "tilt", "x_arcsec": -3600.0, "y_arcsec": 0.0},
        {"index": 4, "kind": "level", "x_arcsec": 0.0, "y_arcsec": 0.0},
    ]
    assert _plan_axes(plan) == {0: "y", 1: "y", 2: "x", 3: "x", 4: "x"}


def test_a_stall_alone_completes_the_last_hold_and_a_late_row_refits_it(short_session, tmp_path):
    """No journal: a record that stops mid-dwell counts its last hold complete once quiet for
    stall_s, though no row arrived (the poll that notices changes nothing else); rows that
    then come for that hold refit it."""
    path, rec, _ = short_session
    lines = path.read_text().splitlines(keepends=True)
    header = next(i for i, ln in enumerate(lines) if ln.startswith("t_s"))
    last_tilt = int(rec.step.max()) - 1
    rows = np.flatnonzero(rec.step == last_tilt)
    cut = header + 1 + int(rows[0]) + 260  # 260 s into the last tilt's 300 s dwell
    p = tmp_path / "stalled.csv"
    p.write_text("".join(lines[:cut]))
    now = [0.0]
    st = LiveState(p, map_runner=_FakeRunner(), clock=lambda: now[0], stall_s=5.0)
    assert st.update()
    assert last_tilt not in st.classical["hold_axis"]
    now[0] = 10.0
    assert st.update()  # quiet for 10 s: the hold is complete, its pair is fitted
    assert last_tilt in st.classical["hold_axis"]
    pairs = st.classical["pairs"]
    with p.open("a") as f:  # the rest of that hold arrives in one poll
        f.write("".join(lines[cut : header + 1 + int(rows[-1]) + 1]))
    v = st.version
    now[0] = 20.0
    assert st.update() and st.version == v + 1
    assert st.classical["pairs"] == pairs and st.classical is not None
    ref = calib.classical_snapshot(calib.partial_record(
        st.record.meta, st.cols(), st.complete_steps(), path=str(p)))  # fmt: skip
    assert st.classical["dg_mgal"] == ref["dg_mgal"]  # the whole hold, not its first 260 s


def test_an_update_landing_while_the_page_connects_is_sent(short_session, tmp_path):
    """The event stream takes the version before the first status: an update that completes
    between them (here: inside status()) reaches the page at once, not never."""
    import threading

    from chekan.live.server import LiveServer

    class _Late(LiveState):
        bumped = False

        def status(self):
            out = super().status()
            if not self.bumped:  # an update lands right after the page's first status
                self.bumped = True
                with self.changed:
                    self.version += 1
                    self.changed.notify_all()
            return out

    st = _Late(short_session[0], map_runner=_FakeRunner())
    st.update()
    srv = LiveServer(("127.0.0.1", 0), st)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        events = []
        with urllib.request.urlopen(srv.url + "events", timeout=5) as r:
            for raw in r:
                if raw.startswith(b"event: "):
                    events.append(raw[7:].strip().decode())
                if len(events) == 2:
                    break
        assert events == ["init", "status"]
    finally:
        srv.stop()
        srv.server_close()


def test_live_on_all_interfaces_prints_the_bound_address_and_a_warning(tmp_path):
    """``chekan live REC --live 0.0.0.0:0`` (and ``acquire --live``, through start_beside):
    the address actually bound, and that anyone on the network can read the page."""
    from chekan.live import start_beside

    rec = tmp_path / "rec.csv"
    rec.write_text(HEADER + COLS)
    p = subprocess.Popen(
        [sys.executable, "-m", "chekan.cli", "live", str(rec), "--live", "0.0.0.0:0"],
        stdout=subprocess.PIPE,
        text=True,
        env=_env(),
    )
    try:
        first, second = p.stdout.readline(), p.stdout.readline()
    finally:
        interrupt(p, 20)
    assert re.match(
        r"live page http://127\.0\.0\.1:(\d+)/ \(pid \d+, bound to 0\.0\.0\.0:\1,", first
    )
    assert second.startswith("warning: the live page listens on every interface (0.0.0.0:")
    assert "anyone on the network can read it (read-only)" in second
    proc, text = start_beside(rec, "0.0.0.0:0")
    try:
        assert proc is not None, text
        lines = text.splitlines()
        assert len(lines) == 2 and "bound to 0.0.0.0:" in lines[0]
        assert lines[1].startswith("warning: the live page listens on every interface")
    finally:
        if proc is not None:
            proc.kill()
            proc.wait(10)


def _serve_in_process(path: Path):
    """The live page of ``path`` in this process (no MAP worker): (server, url)."""
    import threading

    from chekan.live.server import LiveServer

    st = LiveState(path, map_runner=_FakeRunner(), stall_s=1.0)
    srv = LiveServer(("127.0.0.1", 0), st)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    threading.Thread(target=srv.follow, kwargs={"poll_s": 0.1}, daemon=True).start()
    return srv, srv.url


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} absent (make browser)")
@pytest.mark.timeout(300)
def test_the_page_in_a_browser_shows_what_went_wrong(short_session, tmp_path):
    """Issue 33 §5 in a real browser at 1024×768: a binary file, a record running backwards,
    a run stopped by a device error, and a record holding rounds about X and Y."""
    sync_api = pytest.importorskip("playwright.sync_api")
    path, rec, _ = short_session
    binary = tmp_path / "scope.bin"
    binary.write_bytes(bytes(range(256)) * 40)
    lines = path.read_bytes().split(b"\n")
    header = next(i for i, ln in enumerate(lines) if ln.startswith(b"t_s"))
    back_lines = list(lines)
    for i in range(header + 3001, len(lines) - 1):
        f = back_lines[i].split(b",")
        f[0] = str(float(f[0]) - 100).encode()
        back_lines[i] = b",".join(f)
    back = tmp_path / "backwards.csv"
    back.write_bytes(b"\n".join(back_lines))
    stopped = tmp_path / "stopped.csv"
    stopped.write_bytes(b"\n".join(lines[: header + 2001]) + b"\n")
    _journal(
        stopped,
        [
            {"event": "run_start", "utc": "2026-11-25T08:00:00.0Z", "plan": [], "rate_hz": 1.0},
            {"event": "run_stop", "utc": "2026-11-25T08:33:20.0Z", "status": "device_error",
             "exit_code": 1, "message": "platform: TILT (step 3: +1°50', round 1) refused: RANGE"},
        ],
    )  # fmt: skip
    xy = tmp_path / "xy.csv"
    _about_x_in_round_2(rec, path, xy)
    profile = tempfile.mkdtemp(prefix="chekan-chromium-")
    servers = []
    try:
        with sync_api.sync_playwright() as pw:
            ctx = pw.chromium.launch_persistent_context(
                profile,
                executable_path=CHROMIUM,
                args=CHROMIUM_ARGS,
                headless=True,
                viewport={"width": 1024, "height": 768},
            )
            page = ctx.new_page()

            def show(p: Path, expect: str = "") -> str:
                """The alarms once they hold ``expect`` (the page first says "all healthy"
                until the follower has read the file to the line at fault)."""
                srv, url = _serve_in_process(p)
                servers.append(srv)
                page.goto(url)
                page.wait_for_function(
                    "(s) => { const t = document.getElementById('alarms').textContent;"
                    " return t.length > 0 && t.includes(s); }",
                    arg=expect,
                    timeout=30_000,
                )
                box = page.locator("#alarms").bounding_box()
                assert box is not None and box["y"] + box["height"] <= 768, (p, box)
                return page.locator("#alarms").inner_text()

            text = show(binary, f"{binary}: ")
            assert "all healthy" not in text and f"{binary}: " in text and "format" in text
            assert page.locator("#state").inner_text().lower() == "not a record"

            text = show(back, f"{back}:{header + 3002}: ")
            assert f"{back}:{header + 3002}: t_s goes backwards" in text, text
            assert "partial" not in text and "<live>" not in text

            text = show(stopped, "refused: RANGE")
            assert "TILT (step 3: +1°50', round 1) refused: RANGE" in text
            assert page.locator("#remaining").inner_text() == "stopped: device error"
            assert page.locator("#end-lbl").inner_text() == "stopped at"
            assert re.match(r"\d\d:\d\d", page.locator("#end").inner_text())
            assert re.fullmatch(r"-?\d+\.\d+", page.locator("#r-m1").inner_text())

            show(xy)
            # the rows come with the record, their axes with the classical fit (a moment later)
            page.wait_for_function(
                "(() => { const c = [...document.querySelectorAll("
                "'#holds tr.hold-row td:nth-child(4)')];"
                " return c.length > 10 && c.every(td => td.textContent !== '–'); })()",
                timeout=60_000,
            )
            axes = page.locator("#holds tr.hold-row td:nth-child(4)").all_inner_texts()
            assert set(axes) == {"X", "Y"} and axes.count("X") >= 8, axes
            for d in _screenshot_dirs(tmp_path):
                page.screenshot(path=str(d / "live_page_1024.png"))
            ctx.close()
    finally:
        for srv in servers:
            srv.stop()
            srv.server_close()
        shutil.rmtree(profile, ignore_errors=True)
