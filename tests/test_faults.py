"""Issue 33 §2: faults that must not leave a mess behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from children import interrupt

ROOT = Path(__file__).resolve().parents[1]

PARENT = """
import multiprocessing as mp, sys, time
from chekan.archive.reanalyze import configure_worker_env

def work():
    time.sleep(120)  # a calibration that would run on for minutes

if __name__ == "__main__":
    ctx = mp.get_context("spawn")
    with __import__("concurrent.futures").futures.ProcessPoolExecutor(
        1, mp_context=ctx, initializer=configure_worker_env
    ) as ex:
        ex.submit(work)
        time.sleep(1.5)
        print(*[p.pid for p in ex._processes.values()], flush=True)
        time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in state


def test_reanalyze_workers_end_when_their_parent_is_killed(tmp_path):
    script = tmp_path / "parent.py"
    script.write_text(PARENT, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen(
        [sys.executable, str(script)], stdout=subprocess.PIPE, text=True, env=env, cwd=tmp_path
    )
    try:
        (worker,) = (int(x) for x in p.stdout.readline().split())
        assert _alive(worker)
        p.send_signal(signal.SIGKILL)  # kill -9 of reanalyze
        p.wait(timeout=10)
        deadline = time.monotonic() + 5.0
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(worker), "the worker outlived its parent"
    finally:
        p.kill()


def test_acquire_on_a_port_that_does_not_exist_fails_at_once(tmp_path):
    out = tmp_path / "run" / "rec.csv"
    out.parent.mkdir()  # a record's folder must exist (none is created: test_outputs_kinds)
    t0 = time.monotonic()
    p = subprocess.run(
        [
            *(sys.executable, "-m", "chekan.cli", "acquire", "-o", str(out)),
            *("--sensor", str(tmp_path / "ttyUSB9"), "--platform", str(tmp_path / "ttyUSB8")),
            *("--g-local-mgal", "981922.05", "-q"),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=60,
    )
    assert p.returncode == 2 and time.monotonic() - t0 < 30, p.stderr
    assert f"--sensor {tmp_path / 'ttyUSB9'}: no such port" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr
    assert not out.parent.exists() or not any(out.parent.iterdir())  # nothing blocks a retry


def _small_disk(path: Path, size: str) -> bool:
    """Mount a tmpfs of ``size`` at ``path`` (root on Linux); False where that is not allowed."""
    path.mkdir()
    p = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True
    )
    return p.returncode == 0


def test_bayes_on_a_full_disk_is_one_line_and_leaves_nothing(tmp_path, paper_protocol):
    """Issue 33 §2: the posterior's NetCDF on a disk without room was a segfault (HDF5 out
    of space mid-write) and a 2 MB temporary file; now: exit 1, one line, no file."""
    import pytest

    disk = tmp_path / "disk"
    if not _small_disk(disk, "1m"):
        pytest.skip("cannot mount a small tmpfs here (needs root on Linux)")
    try:
        (disk / "fill").write_bytes(b"\0" * 900_000)
        p = subprocess.run(
            [
                *(sys.executable, "-m", "chekan.cli", "calibrate", str(paper_protocol)),
                *("--method", "bayes", "--quick", "-q", "-o", str(disk / "r.json")),
            ],
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            timeout=300,
        )
        assert p.returncode == 1, (p.returncode, p.stderr)
        assert "no room for the posterior" in p.stderr and "Traceback" not in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1, p.stderr
        assert sorted(x.name for x in disk.iterdir()) == ["fill"]
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


def test_save_netcdf_refuses_before_writing_without_room(tmp_path, monkeypatch):
    import shutil
    from collections import namedtuple

    import arviz as az
    import numpy as np
    import pytest

    from inference.arviz_io import netcdf_size_bound, save_netcdf

    idata = az.from_dict(posterior={"x": np.zeros((2, 1000))})
    assert netcdf_size_bound(idata) >= 16_000
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(1, 1, 1000))
    with pytest.raises(OSError, match="no room for the posterior") as e:
        save_netcdf(idata, tmp_path / "post.nc")
    assert e.value.errno == 28 and list(tmp_path.iterdir()) == []


LONG_PROGRAM_TOML = (
    'name = "long"\nangles = ["1°", "2°"]\ndwell_s = 300\nsettle_s = 20\nrounds = 2\n'
)


def _record_ends_whole(rec: Path) -> None:
    """The record parses, ends with a complete row and its times increase."""
    import numpy as np

    from chekan.records import read_record

    assert rec.read_bytes().endswith(b"\n")
    r = read_record(rec)
    assert r.n > 0 and np.all(np.diff(r.t_s) > 0)


def test_acquire_on_a_full_disk_levels_closes_and_resumes(tmp_path):
    """Issue 33 §2: a full disk during ``acquire`` printed thread tracebacks and left the
    platform tilted; now: levelled, record closed at a whole row, one line, exit 1, and the
    run resumes once the disk has room."""
    import pytest

    from hw.emulator import PtyEmulator
    from hw.journal import journal_path, read_journal

    disk = tmp_path / "disk"
    if not _small_disk(disk, "96k"):
        pytest.skip("cannot mount a small tmpfs here (needs root on Linux)")
    prog = tmp_path / "long.toml"
    prog.write_text(LONG_PROGRAM_TOML, encoding="utf-8")
    rec = disk / "rec.csv"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    try:
        with PtyEmulator(str(tmp_path / "s"), str(tmp_path / "p"), speed=100, seed=4) as emu:
            p = subprocess.run(
                [
                    *(sys.executable, "-m", "chekan.cli", "acquire", "-q", "--out", str(rec)),
                    *("--sensor", emu.sensor_url, "--platform", emu.platform_url),
                    *("--program", str(prog), "--g-local-mgal", "981922.05"),
                ],
                capture_output=True,
                text=True,
                env=env,
                timeout=120,
            )
            platform = emu.emulator.platform
            levelled = (platform.target, platform.state)
        assert p.returncode == 1, (p.returncode, p.stdout, p.stderr)
        assert "Traceback" not in p.stderr and "Exception" not in p.stderr, p.stderr
        first = p.stdout.splitlines()[1]  # after the program's line
        assert first.startswith(f"acquisition stopped (exit 1): cannot write {disk}/rec.csv")
        assert "No space left on device" in first and "--resume" in first, first
        assert "levelled: yes" in p.stdout
        assert levelled == ((0.0, 0.0), "HOLD")
        _record_ends_whole(rec)
        jp = journal_path(rec)
        assert jp.read_bytes().endswith(b"\n")  # whole events (run_stop only if it fitted)
        assert read_journal(jp)[0]["event"] == "run_start"

        subprocess.run(["mount", "-o", "remount,size=4m", str(disk)], check=True)
        with PtyEmulator(str(tmp_path / "s"), str(tmp_path / "p"), speed=100, seed=5) as emu:
            again = subprocess.run(
                [
                    *(sys.executable, "-m", "chekan.cli", "acquire", "-q"),
                    *("--resume", str(rec), "--sensor", emu.sensor_url),
                    *("--platform", emu.platform_url),
                ],
                capture_output=True,
                text=True,
                env=env,
                timeout=120,
            )
        assert again.returncode == 0, again.stdout + again.stderr
        _record_ends_whole(rec)
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


class _FillsUp:
    """A file on a disk that fills up: a write puts a few bytes, then ENOSPC."""

    def __init__(self, f):
        self.f = f

    def write(self, data):
        import errno

        self.f.write(bytes(data[:7]))
        raise OSError(errno.ENOSPC, "No space left on device")

    def __getattr__(self, name):
        return getattr(self.f, name)


def test_a_failed_raw_log_write_stops_the_run_without_a_thread_traceback(tmp_path, monkeypatch):
    """The raw log is written by the ports' reader threads: a full disk there raised in a
    thread (traceback, reader dead). Now the failure stops the run like any other."""
    import threading

    import hw.linkio
    from chekan.physics.program import build_program
    from hw.acquisition import EXIT_DEVICE, Options, acquire
    from hw.emulator import InProcessEmulator

    real = hw.linkio.append_whole

    def fills_up(f, data, good):
        if good + len(data) > 20_000:  # ~200 samples into the run
            return real(_FillsUp(f), data, good)
        return real(f, data, good)

    monkeypatch.setattr(hw.linkio, "append_whole", fills_up)
    thread_errors: list[object] = []
    monkeypatch.setattr(threading, "excepthook", thread_errors.append)
    program = build_program([1.0, 2.0], dwell_s=60, settle_s=20, rounds=1, name="short")
    with InProcessEmulator("full-raw-log", speed=300, seed=8) as emu:
        o = Options(sensor_url=emu.sensor_url, platform_url=emu.platform_url, timeout_s=2.0)
        o.reply_timeout_s = 0.5
        rec = tmp_path / "rec.csv"
        s = acquire(rec, program, o, g_local_mgal=981922.05, report=None)
    assert thread_errors == []
    assert s.exit_code == EXIT_DEVICE and s.status == "stopped" and s.levelled
    assert s.message.startswith(f"cannot write {rec}.raw.log: No space left on device")
    assert s.steps_done < 6
    raw = Path(f"{rec}.raw.log").read_bytes()
    assert raw.endswith(b"\n")  # cut back to its last whole line
    _record_ends_whole(rec)


def test_a_record_write_that_fails_part_way_is_cut_back(tmp_path):
    """RecordWriter: a batch that does not fit leaves the file at its last complete row
    (a valid, resumable record) and closes the writer."""

    import pytest

    from chekan.records import RecordWriter, read_record

    path = tmp_path / "rec.csv"
    w = RecordWriter(path, {"serial": "1", "g_local_mgal": "981922.05"})
    w.write_rows([0.0, 1.0], [1.0, 1.0], [2.0, 2.0], [0.0, 0.0], [0.0, 0.0], [0, 0], None)
    size = path.stat().st_size

    w._f = _FillsUp(w._f)
    with pytest.raises(OSError, match="No space"):
        w.write_rows([2.0], [1.0], [2.0], [0.0], [0.0], [1], None)
    assert w.closed and w.error is not None and path.stat().st_size == size
    assert read_record(path).n == 2
    w.close()  # idempotent after the failure
    again = RecordWriter(path, None, append=True)
    again.write_row(2.0, 1.0, 2.0, 0.0, 0.0, 1)
    again.close()
    assert list(read_record(path).t_s) == [0.0, 1.0, 2.0] and again.torn_path is None


def test_any_fatal_error_of_acquisition_levels_and_closes_first(tmp_path, monkeypatch):
    """Not only the disk: whatever ends a run (here an unexpected error in the recorder)
    levels the platform, closes the record at a whole row and says so in one line."""
    from chekan.physics.program import build_program
    from hw.acquisition import EXIT_DEVICE, Options, acquire
    from hw.acquisition.recorder import Recorder
    from hw.emulator import InProcessEmulator

    real = Recorder.add_sample

    def breaks(self, t, g, angles, step):
        if self.stats.samples >= 150:
            raise RuntimeError("a bug in the recorder")
        return real(self, t, g, angles, step)

    monkeypatch.setattr(Recorder, "add_sample", breaks)
    program = build_program([1.0, 2.0], dwell_s=60, settle_s=20, rounds=1, name="short")
    with InProcessEmulator("fatal-bug", speed=300, seed=8) as emu:
        o = Options(sensor_url=emu.sensor_url, platform_url=emu.platform_url, timeout_s=2.0)
        o.reply_timeout_s = 0.5
        rec = tmp_path / "rec.csv"
        s = acquire(rec, program, o, g_local_mgal=981922.05, report=None)
        platform = emu.emulator.platform
        assert (platform.target, platform.state) == ((0.0, 0.0), "HOLD")
    assert s.exit_code == EXIT_DEVICE and s.levelled and s.steps_done < 6
    assert s.format().splitlines()[0] == (
        "acquisition error (exit 1): unexpected RuntimeError: a bug in the recorder"
    )
    _record_ends_whole(rec)


def test_acquire_on_a_disk_already_full_leaves_nothing_that_blocks_a_retry(tmp_path):
    """No room even for the record's header: one line naming the record, exit 1, and no
    empty record, journal or raw log left to make the retry say 'exists'."""
    import pytest

    from hw.emulator import PtyEmulator

    disk = tmp_path / "disk"
    if not _small_disk(disk, "64k"):
        pytest.skip("cannot mount a small tmpfs here (needs root on Linux)")
    prog = tmp_path / "long.toml"
    prog.write_text(LONG_PROGRAM_TOML, encoding="utf-8")
    rec = disk / "rec.csv"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    try:
        (disk / "fill").write_bytes(b"\0" * 65536)
        with PtyEmulator(str(tmp_path / "s"), str(tmp_path / "p"), speed=100, seed=4) as emu:
            argv = [
                *(sys.executable, "-m", "chekan.cli", "acquire", "-q", "--out", str(rec)),
                *("--sensor", emu.sensor_url, "--platform", emu.platform_url),
                *("--program", str(prog), "--g-local-mgal", "981922.05"),
            ]
            p = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120)
            assert p.returncode == 1, (p.stdout, p.stderr)
            assert "Traceback" not in p.stderr, p.stderr
            first = p.stdout.splitlines()[1]
            assert first == (
                f"acquisition stopped (exit 1): cannot write {rec}: No space left on device; "
                "nothing was recorded: the empty record and its journal were removed, so the "
                "same record can be started again"
            )
            assert "levelled: yes" in p.stdout
            assert sorted(x.name for x in disk.iterdir()) == ["fill"]
            (disk / "fill").unlink()  # room again: the same command starts the run
            p2 = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True, env=env)
            try:
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline and not (
                    rec.exists() and rec.stat().st_size > 2000
                ):
                    time.sleep(0.1)
                assert rec.stat().st_size > 2000  # rows are being recorded
            finally:
                interrupt(p2, 60)
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)
