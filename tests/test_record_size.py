"""Issue 33 §2: the largest record the joint methods take, refused above it before reading."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from chekan.pipeline import MAX_JOINT_ROWS
from chekan.records import read_record
from chekan.records.framing import count_rows

ROOT = Path(__file__).resolve().parents[1]
HEADER = "# format: chekan-record/1\n# serial: 46\n# g_local_mgal: 981922.05\n"
COLS = "t_s,m1_pix,m2_pix,tilt_x_arcsec,tilt_y_arcsec,step,temp_c\n"


def _record(path: Path, n: int, *, bom: bool = False, last_newline: bool = True) -> Path:
    rows = "".join(f"{i},1000.5,990.25,0.1,-0.2,0,45.0\n" for i in range(n))
    text = HEADER + COLS + (rows if last_newline else rows.rstrip("\n"))
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode("ascii"))
    return path


@pytest.mark.parametrize(
    ("n", "bom", "last_newline"), [(0, False, True), (1, False, True), (7, True, False)]
)
def test_count_rows_agrees_with_the_reader(tmp_path, n, bom, last_newline):
    import warnings

    p = _record(tmp_path / "r.csv", n, bom=bom, last_newline=last_newline)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert count_rows(p, chunk_bytes=16) == n == read_record(p).n


@pytest.mark.parametrize("method", ["map", "bayes"])
def test_a_record_beyond_the_limit_is_refused_before_it_is_read(tmp_path, method):
    """A 1 000 000-row record took 8.8 min and 10.2 GB with --method map: now a record of
    more than MAX_JOINT_ROWS rows is refused at once (exit 2), naming file, size and limit."""
    big = _record(tmp_path / "big.csv", MAX_JOINT_ROWS + 1)
    p = subprocess.run(
        [
            *(sys.executable, "-m", "chekan.cli", "calibrate", str(big), "--method", method),
            *("-q", "-o", str(tmp_path / "r.json")),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert p.returncode == 2, p.stderr
    line = p.stderr.strip()
    assert "\n" not in line and "Traceback" not in line
    assert line == (
        f"chekan: error: {big}: 400 001 rows ({big.stat().st_size / 1e6:.1f} MB): --method "
        f"{method} takes records of at most 400 000 rows (about 111 h at 1 Hz); split the "
        "record, or use --method classical"
    )
    assert not (tmp_path / "r.json").exists()
