"""Issue 33 §4: no ResourceWarning or leaked-semaphore warning at exit (Python's dev mode
prints every unclosed file, socket and semaphore)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _dev_run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-X", "dev", "-W", "error::ResourceWarning", "-m", "chekan.cli", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=300,
    )


@pytest.mark.parametrize("command", ["calibrate", "reanalyze"])
def test_no_resource_warnings_at_exit(command, paper_protocol, tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    shutil.copy(paper_protocol, folder / "p46.csv")
    args = {
        "calibrate": ["calibrate", str(folder / "p46.csv"), "-o", str(tmp_path / "r.json")],
        "reanalyze": ["reanalyze", str(folder), "-j", "2", "-q", "--db", str(tmp_path / "a.db")],
    }[command]
    p = _dev_run(args, tmp_path)
    assert p.returncode == 0, p.stderr
    for word in ("ResourceWarning", "leaked", "unclosed", "Traceback"):
        assert word not in p.stderr, p.stderr
