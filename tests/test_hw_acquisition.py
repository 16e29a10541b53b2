"""Acquisition end to end against the emulator over pseudo-terminals: a short program,
every fault of the plan, kill -9 + resume, Ctrl-C, and the command line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from children import interrupt

from chekan.errors import ChekanError
from chekan.physics.program import build_program
from chekan.records import read_record
from hw.acquisition import (
    EXIT_DEVICE,
    EXIT_GAVE_UP,
    EXIT_INTERRUPTED,
    Options,
    acquire,
    resume,
)
from hw.acquisition.resume import resume_state
from hw.emulator import InProcessEmulator, PtyEmulator
from hw.faults import parse_faults
from hw.journal import Journal, journal_path, raw_log_path, read_journal

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = build_program([1.0, 2.0], dwell_s=60, settle_s=20, rounds=1, name="short")
N = 60  # dwell samples per step at 1 Hz
PROGRAM_TOML = 'name = "short"\nangles = ["1°", "2°"]\ndwell_s = 60\nsettle_s = 20\nrounds = 1\n'
HEADER_KEYS = {
    "format",
    "serial",
    "platform_serial",
    "sample_rate_hz",
    "instrument",
    "model",
    "g_local_mgal",
    "program",
    "program_dwell_s",
    "program_settle_s",
    "started",
}


def pty_emu(tmp_path: Path, **kw) -> PtyEmulator:
    kw.setdefault("seed", 3)
    return PtyEmulator(str(tmp_path / "sensor"), str(tmp_path / "platform"), **kw)


def run(tmp_path: Path, emu, **opts):
    o = Options(sensor_url=emu.sensor_url, platform_url=emu.platform_url, timeout_s=2.0)
    o.reply_timeout_s = 0.5
    for k, v in opts.items():
        setattr(o, k, v)
    rec = tmp_path / "rec.csv"
    s = acquire(rec, PROGRAM, o, g_local_mgal=981922.05, meta={"site": "Lab"}, report=None)
    return rec, s


def wait_level(emu, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    p = emu.emulator.platform
    while time.monotonic() < deadline and not (p.target == (0.0, 0.0) and p.state == "HOLD"):
        time.sleep(0.02)
    assert p.target == (0.0, 0.0) and p.state == "HOLD", (p.target, p.state)


def last_run(step: np.ndarray, k: int) -> np.ndarray:
    w = np.flatnonzero(step == k)
    br = np.flatnonzero(np.diff(w) != 1)
    return w[br[-1] + 1 :] if br.size else w


def whole_runs(rec) -> dict[int, int]:
    """Rows of each step's last uninterrupted run: consecutive rows of the step, one sample
    period apart (no gap in t_s)."""
    out: dict[int, int] = {}
    n = 0
    for i in range(rec.n):
        k = int(rec.step[i])
        go_on = i > 0 and rec.step[i - 1] == k and rec.t_s[i] - rec.t_s[i - 1] == 1
        n = n + 1 if go_on else 1
        if k >= 0:
            out[k] = n
    return out


def check_record(rec_path: Path, n_steps: int = 6, complete: bool = True):
    """Parses; header keys; t_s strictly increasing; each step's dwell exact on the sample
    clock and whole: its last run of rows spans the dwell without a gap."""
    rec = read_record(rec_path)
    assert HEADER_KEYS <= set(rec.meta)
    assert rec.meta["program"] == "short" and rec.meta["g_local_mgal"] == "981922.05"
    assert rec.meta["site"] == "Lab" and rec.meta["sample_rate_hz"] == "1"
    t = rec.t_s
    assert np.all(np.diff(t) > 0) and t[0] == 0
    events = read_journal(journal_path(rec_path))
    done = {e["step"]: e for e in events if e["event"] == "step_done"}
    if complete:
        assert sorted(done) == list(range(n_steps))
    for k, e in done.items():
        t0 = e["t_s_first"]
        window = (t >= t0) & (t < t0 + N)
        run_rows = last_run(rec.step, k)
        assert np.array_equal(run_rows, np.flatnonzero(window)), f"step {k}"
        lost_in_window = N - window.sum()
        assert e["samples"] == N - lost_in_window
        assert np.all(np.diff(t[run_rows]) == 1), f"step {k}: a gap in its dwell"
    if complete:
        assert whole_runs(rec) == dict.fromkeys(range(n_steps), N)
    return rec, events


def gaps_of(rec) -> tuple[int, int]:
    dt = np.diff(rec.t_s)
    return int((dt > 1).sum()), int((dt - 1).sum())


def test_short_program_end_to_end(tmp_path):
    with pty_emu(tmp_path, speed=0, seq_start=65400) as emu:  # seq wraps mid-run
        rec_path, s = run(tmp_path, emu)
        wait_level(emu)
    assert (s.status, s.exit_code, s.steps_done, s.levelled) == ("completed", 0, 6, True)
    rec, events = check_record(rec_path)
    for k in range(6):
        assert (rec.step == k).sum() == N  # no faults: exactly dwell × rate rows per step
    assert rec.meta["serial"] == "SIM-1" and rec.meta["platform_serial"] == "SIM-PLATFORM"
    assert rec.n == s.samples and s.gaps == s.lost_samples == 0
    assert s.reconnects == {"sensor": 0, "platform": 0}
    assert all(v == 0 for v in s.dropped["sensor"].values())
    # moving samples are recorded too, with the platform angles and an empty step
    moving = rec.step == -1
    assert moving.sum() > 6 and np.isfinite(rec.tilt_y_arcsec[moving]).all()
    held = rec.tilt_y_arcsec[last_run(rec.step, 3)]
    assert np.abs(held - 7200).max() < 3
    kinds = [e["event"] for e in events]
    assert kinds[0] == "run_start" and kinds[-1] == "run_stop" and "levelled" in kinds
    assert events[-1]["status"] == "completed" and events[-1]["exit_code"] == 0
    raw = raw_log_path(rec_path).read_text().splitlines()
    assert any(x.startswith("sensor< $GRV,") for x in raw)
    assert any(x.startswith("platform> $PLQ,TILT,") for x in raw)


def test_in_process_url_end_to_end_and_level_only_resume(tmp_path):
    with InProcessEmulator("acq-test", speed=0, seed=8) as emu:
        rec_path, s = run(tmp_path, emu)
        assert s.exit_code == 0
        check_record(rec_path)
        # killed while levelling at the end: every step done, no run_stop -> resume levels
        jp = journal_path(rec_path)
        lines = jp.read_text().splitlines()
        jp.write_text("\n".join(lines[:-3]) + "\n")
        n_before = read_record(rec_path).n
        with Journal(jp):  # a runner holds the journal: a second one refuses at once
            busy = resume(rec_path, report=None)
        assert busy.exit_code == 2 and "locked" in busy.message
        s2 = resume(rec_path, report=None)
    assert s2.exit_code == 0 and s2.levelled and s2.steps_done == 6
    events = read_journal(jp)
    assert [e["from_step"] for e in events if e["event"] == "resume"] == [6]
    after = read_record(rec_path)
    assert after.n >= n_before and np.all(np.diff(after.t_s) > 0)


def test_garbage_and_bad_checksums_are_counted(tmp_path):
    plan = parse_faults("garbage=0.05;badsum=0.05")
    with pty_emu(tmp_path, speed=0, faults=plan) as emu:
        rec_path, s = run(tmp_path, emu)
        stats = emu.emulator.stats
    assert s.exit_code == 0
    check_record(rec_path)
    for port in ("sensor", "platform"):
        d = s.dropped[port]
        assert d["bad_checksum"] > 0 and d["garbage_bytes"] > 0 and d["torn"] > 0
        assert d["bad_checksum"] <= stats[f"{port}_badsum"]
    rec = read_record(rec_path)
    assert gaps_of(rec) == (s.gaps, s.lost_samples)


def test_dropped_lines_are_gaps_in_t_s(tmp_path):
    with pty_emu(tmp_path, speed=0, faults=parse_faults("drop=0.03")) as emu:
        rec_path, s = run(tmp_path, emu)
    assert s.exit_code == 0
    rec, events = check_record(rec_path)
    assert s.gaps > 0 and gaps_of(rec) == (s.gaps, s.lost_samples)
    assert sum(e["lost"] for e in events if e["event"] == "gap") == s.lost_samples
    assert s.samples == rec.n


def test_stall_and_vanishing_ports_reconnect(tmp_path):
    plan = parse_faults("stall=sensor@120+100;vanish=sensor@260+60;vanish=platform@330+60")
    with pty_emu(tmp_path, speed=100, faults=plan) as emu:
        rec_path, s = run(tmp_path, emu, timeout_s=0.3, give_up_s=20.0)
        wait_level(emu)
    assert s.exit_code == 0, s.message
    rec, events = check_record(rec_path)
    assert s.reconnects["sensor"] >= 2 and s.reconnects["platform"] >= 1
    assert sum(e["event"] == "reconnect" for e in events) == sum(s.reconnects.values())
    dt = np.diff(rec.t_s)
    assert dt.max() >= 100  # the stall: seq kept counting, t_s jumps with it
    assert gaps_of(rec) == (s.gaps, s.lost_samples)


def test_platform_fault_recommands_tilt(tmp_path):
    with pty_emu(tmp_path, speed=0, faults=parse_faults("fault=100+20")) as emu:
        rec_path, s = run(tmp_path, emu)
        emu_events = [w for _, w in emu.emulator.events]
    assert s.exit_code == 0
    _rec, events = check_record(rec_path)
    assert s.faults == 1 and s.recommands >= 1
    assert any(e["event"] == "tilt" and e["reason"] == "fault" for e in events)
    assert "FAULT" in emu_events
    after = emu_events[emu_events.index("FAULT") + 1 :]
    assert any(w.startswith("TILT") for w in after[: after.index("MOVE")])  # re-sent, then moved


CHAOS = "drop=0.01;garbage=0.03;badsum=0.02;stall=sensor@150+40;fault=300+20;seed=11"


def test_every_hold_is_dwelt_whole_under_faults(tmp_path):
    """Lost lines, garbage, bad checksums, a stalled sensor and a platform FAULT: every hold
    of the record ends in an uninterrupted run of rows spanning its whole dwell."""
    with pty_emu(tmp_path, speed=0, faults=parse_faults(CHAOS)) as emu:
        rec_path, s = run(tmp_path, emu)
    assert s.exit_code == 0, s.message
    rec, events = check_record(rec_path)
    assert s.gaps > 0 and s.lost_samples >= 40 and s.faults == 1  # the faults did strike
    cuts = [e for e in events if e["event"] == "hold_lost"]
    assert {e["state"] for e in cuts} >= {"GAP", "FAULT"} and len(cuts) == s.hold_restarts
    for e in cuts:  # the row after a cut belongs to no step: the runs stay apart
        i = int(np.searchsorted(rec.t_s, e["t_s"]))
        if e["state"] == "GAP":
            assert rec.t_s[i] == e["t_s"] and rec.step[i] == -1 and rec.step[i - 1] == e["step"]


def test_a_dwell_cut_too_often_gives_up_levelled_and_resumable(tmp_path):
    with pty_emu(tmp_path, speed=0, faults=parse_faults("drop=0.2")) as emu:
        rec_path, s = run(tmp_path, emu, max_dwell_cuts=3)
        wait_level(emu)
    assert (s.status, s.exit_code, s.levelled) == ("gave_up", EXIT_GAVE_UP, True)
    assert "step 0 (" in s.message and "cut short 3 times" in s.message, s.message
    events = read_journal(journal_path(rec_path))
    assert [e["state"] for e in events if e["event"] == "hold_lost"] == ["GAP"] * 3
    assert events[-1]["event"] == "run_stop" and events[-1]["status"] == "gave_up"
    gave_up_at = [e for e in events if e["event"] == "hold_lost"][-1]["t_s"]
    # the record stays open through the give-up (its rows while the platform levels may all
    # be among the 20 % of lines dropped, or come after the platform reports level: seen
    # once in a loaded full run, so no row after it is required)
    assert read_record(rec_path).t_s[-1] >= gave_up_at
    state, *_ = resume_state(rec_path)
    assert state is not None and state.first_step == 0 and not state.done


def test_lost_tilt_reply_is_not_resent_when_the_platform_moves(tmp_path):
    with pty_emu(tmp_path, speed=0, faults=parse_faults("tiltmute=2")) as emu:
        rec_path, s = run(tmp_path, emu)
        n_tilts = emu.emulator.tilt_commands
    assert s.exit_code == 0
    _, events = check_record(rec_path)
    assert any(e["event"] == "reply_lost_command_obeyed" for e in events)
    assert n_tilts == 6  # one per step: the muted one was not sent again


def test_tilt_error_stops_cleanly(tmp_path):
    with pty_emu(tmp_path, speed=0, faults=parse_faults("tilterr=BUSY@3")) as emu:
        rec_path, s = run(tmp_path, emu)
        wait_level(emu)
    assert s.exit_code == EXIT_DEVICE and s.status == "device_error"
    assert "BUSY" in s.message and "TILT" in s.message
    assert s.levelled and s.steps_done == 2
    _rec, events = check_record(rec_path, complete=False)
    assert events[-1]["event"] == "run_stop" and events[-1]["exit_code"] == EXIT_DEVICE


def test_existing_record_and_protected_meta_refused(tmp_path):
    rec = tmp_path / "rec.csv"
    rec.write_text("x")
    with pytest.raises(ChekanError, match="exists"):
        acquire(rec, PROGRAM, Options(), g_local_mgal=1.0)
    with pytest.raises(ChekanError, match="serial"):
        acquire(tmp_path / "b.csv", PROGRAM, Options(), g_local_mgal=1.0, meta={"serial": "9"})
    with pytest.raises(ChekanError, match="journal"):
        resume(tmp_path / "none.csv")


def _acquire_cmd(emu, rec: Path, prog: Path, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-c",
        "import sys; from hw.cli import main; sys.exit(main(sys.argv[1:]))",
        "acquire",
        "--sensor",
        emu.sensor_url,
        "--platform",
        emu.platform_url,
        "--out",
        str(rec),
        "--program",
        str(prog),
        "--g-local-mgal",
        "981922.05",
        "--meta",
        "site=Lab",
        "--quiet",
        *extra,
    ]


def _wait_event(rec: Path, pred, timeout_s: float = 30.0) -> None:
    jp = journal_path(rec)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if jp.exists() and any(pred(e) for e in read_journal(jp)):
            return
        time.sleep(0.02)
    raise AssertionError("journal event did not come")


@pytest.mark.slow
def test_kill9_mid_dwell_then_resume(tmp_path):
    prog = tmp_path / "short.toml"
    prog.write_text(PROGRAM_TOML, encoding="utf-8")
    rec = tmp_path / "rec.csv"
    with pty_emu(tmp_path, speed=100, seed=5, seq_start=65500) as emu:
        p = subprocess.Popen(_acquire_cmd(emu, rec, prog, "--timeout-s", "1"), cwd=ROOT)
        try:
            _wait_event(rec, lambda e: e["event"] == "hold" and e["step"] == 2)
            time.sleep(0.15)  # ~15 samples into the dwell of step 2
        finally:
            os.kill(p.pid, signal.SIGKILL)
            p.wait()
        before = read_record(rec)
        partial = (before.step == 2).sum()
        assert 0 < partial < N  # killed mid-dwell
        with open(rec, "ab") as f:  # as if killed in the middle of writing a row
            f.write(b"%d,1031.1" % (before.t_s[-1] + 1))
        s = resume(rec, report=None)
        wait_level(emu)
    assert s.exit_code == 0 and s.steps_done == 6, s.message
    assert Path(f"{rec}.torn-1").read_bytes().startswith(b"%d," % (before.t_s[-1] + 1))
    after, events = check_record(rec)
    assert np.array_equal(after.t_s[: before.n], before.t_s)  # nothing rewritten
    assert np.unique(after.t_s).size == after.n  # no duplicated t_s
    assert after.t_s[before.n] > before.t_s[-1]
    assert (after.step == 2).sum() == partial + N  # partial run kept, step re-run in full
    assert [k for k in range(6) if (after.step == k).sum() < N] == []
    kinds = [e["event"] for e in events]
    assert "resume" in kinds
    res = events[kinds.index("resume")]
    assert res["from_step"] == 2 and res["steps_done"] == [0, 1]
    assert events[-1]["event"] == "run_stop" and events[-1]["status"] == "completed"
    assert resume(rec, report=None).message.startswith("nothing to resume")


@pytest.mark.slow
def test_kill9_mid_hold_under_faults_then_resume_dwells_every_hold_whole(tmp_path):
    """Faults of every kind and a kill -9 in a hold, then --resume: nothing lost or
    duplicated, and every hold ends in an uninterrupted run of its whole dwell."""
    prog = tmp_path / "short.toml"
    prog.write_text(PROGRAM_TOML, encoding="utf-8")
    rec = tmp_path / "rec.csv"
    faults = parse_faults(CHAOS + ";stall=sensor@400+40;stall=sensor@700+40")
    with pty_emu(tmp_path, speed=100, seed=5, faults=faults) as emu:
        p = subprocess.Popen(_acquire_cmd(emu, rec, prog, "--timeout-s", "0.3"), cwd=ROOT)
        try:
            _wait_event(rec, lambda e: e["event"] == "hold" and e["step"] == 2)
            time.sleep(0.15)  # ~15 samples into the dwell of step 2
        finally:
            os.kill(p.pid, signal.SIGKILL)
            p.wait()
        before = read_record(rec)
        assert 0 < whole_runs(before).get(2, 0) < N  # killed mid-hold
        s = resume(rec, report=None)
        wait_level(emu)
    assert s.exit_code == 0 and s.steps_done == 6, s.message
    after, events = check_record(rec)
    assert np.array_equal(after.t_s[: before.n], before.t_s)  # nothing rewritten
    assert np.unique(after.t_s).size == after.n  # no duplicated t_s
    assert whole_runs(after) == dict.fromkeys(range(6), N)
    assert [e["from_step"] for e in events if e["event"] == "resume"] == [2]
    assert max(e["lost"] for e in events if e["event"] == "gap") >= 30  # a stall struck


@pytest.mark.slow
def test_sigint_levels_platform(tmp_path):
    prog = tmp_path / "short.toml"
    prog.write_text(PROGRAM_TOML, encoding="utf-8")
    rec = tmp_path / "rec.csv"
    with pty_emu(tmp_path, speed=100, seed=6) as emu:
        p = subprocess.Popen(_acquire_cmd(emu, rec, prog), cwd=ROOT, stdout=subprocess.PIPE)
        _wait_event(rec, lambda e: e["event"] == "hold" and e["step"] == 1)
        assert emu.emulator.platform.target == (0.0, 3600.0)
        out, _ = interrupt(p, 30)
        wait_level(emu)
    assert p.returncode == EXIT_INTERRUPTED
    assert b"interrupted" in out and b"levelled: yes" in out
    events = read_journal(journal_path(rec))
    assert events[-1]["status"] == "interrupted"
    read_record(rec)


@pytest.mark.slow
def test_command_line_emulate_and_acquire(tmp_path):
    prog = tmp_path / "short.toml"
    prog.write_text(PROGRAM_TOML, encoding="utf-8")
    sensor, platform, rec = tmp_path / "s", tmp_path / "p", tmp_path / "rec.csv"
    main = "import sys; from hw.cli import main; sys.exit(main(sys.argv[1:]))"
    emu = subprocess.Popen(
        [sys.executable, "-c", main, "emulate", "--sensor", str(sensor), "--platform",
         str(platform), "--speed", "0", "--seed", "9", "--duration-s", "120"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        first = emu.stdout.readline()
        assert first.startswith("sensor") and "/dev/pts/" in first
        cmd = [sys.executable, "-c", main, "acquire", "--sensor", str(sensor), "--platform",
               str(platform), "--out", str(rec), "--program", str(prog), "--g-local-mgal",
               "981922.05", "--meta", "site=Lab", "--quiet"]  # fmt: skip
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stdout + done.stderr
        assert "acquisition completed" in done.stdout
        again = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert again.returncode == 2 and "exists" in again.stderr
    finally:
        interrupt(emu, 30)
    assert emu.returncode == 0
    assert not sensor.exists()  # the emulator removed its symlinks
    check_record(rec)


def test_summary_printed_once(tmp_path, capsys):
    """Regression: ``chekan acquire`` (and the demo) printed the summary table twice."""
    from hw.cli import main

    prog = tmp_path / "short.toml"
    prog.write_text(PROGRAM_TOML, encoding="utf-8")
    handler = signal.getsignal(signal.SIGTERM)
    try:
        with InProcessEmulator("acq-print-once", speed=0, seed=8) as emu:
            code = main(_acquire_cmd(emu, tmp_path / "rec.csv", prog)[3:])
            out = capsys.readouterr().out
            assert code == 0
            assert out.count("acquisition completed (exit 0)") == 1
            assert out.count("  steps      6/6 done") == 1
            # the library itself prints nothing: its caller (CLI, demo) shows the summary
            o = Options(sensor_url=emu.sensor_url, platform_url=emu.platform_url)
            s = acquire(tmp_path / "b.csv", PROGRAM, o, g_local_mgal=981922.05)
            assert s.exit_code == 0 and capsys.readouterr().out == ""
    finally:
        signal.signal(signal.SIGTERM, handler)
