"""Issue 33 §2: faults that must not leave a mess behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

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
