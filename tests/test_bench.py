"""Cheap checks of the benchmark helpers (``bench/``): the NumPy reference fit and the table."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.classical_ref import numpy_classical_fit
from bench.table import Row, format_table


def test_numpy_reference_agrees_with_the_classical_method(short_session):
    from chekan.classical import calibrate_record

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
