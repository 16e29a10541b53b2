"""The stacks a crashed test process leaves are printed with the crashing thread last."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _report(folder: Path) -> str:
    """What ``tests/crash_report.py FOLDER`` prints."""
    run = subprocess.run(
        [sys.executable, str(HERE / "crash_report.py"), str(folder)],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return run.stdout


def test_a_segfault_in_a_thread_is_reported_with_that_thread_last(tmp_path):
    code = textwrap.dedent(
        f"""
        import ctypes, faulthandler, threading, time
        log = open({str(tmp_path / "gw7.log")!r}, "w")
        faulthandler.enable(file=log, all_threads=True)
        def idle_beside():
            time.sleep(30)
        def crash_in_the_loader():
            ctypes.string_at(0)
        threading.Thread(target=idle_beside, daemon=True).start()
        t = threading.Thread(target=crash_in_the_loader)
        t.start()
        t.join()
        """
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60)
    assert run.returncode != 0
    (tmp_path / "gw0.log").write_text("")  # a worker that did not crash
    out = _report(tmp_path)
    assert out.startswith("== gw7 died: Fatal Python error: Segmentation fault")
    assert "gw0" not in out and "Extension modules" not in out
    last = out[out.rindex("Current thread") :]
    assert "crash_in_the_loader" in last and "idle_beside" not in last
    assert "idle_beside" in out


def test_no_crash_says_so(tmp_path):
    out = _report(tmp_path)
    assert out.startswith("no crashed process left its stacks")
