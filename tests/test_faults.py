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
