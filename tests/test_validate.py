"""A small run of the coverage study (``python -m chekan.validate``) on simulated sessions."""

import json

import numpy as np

from chekan.validate import format_summary, run_study


def test_small_coverage_study(tmp_path):
    s = run_study(6, tmp_path, cases=("typical",), quick=True, seed=11, progress=False)
    e = s["all"]
    # honest uncertainty: mean z² ≈ 1; a 3× underestimated sd would give ≈ 9
    for p in ("b1", "b2", "a"):
        assert e[f"map/{p}"]["mean_z2"] < 4.0, (p, e[f"map/{p}"])
        assert e[f"map/{p}"]["coverage_95"] >= 4 / 6
    # the joint model is at least as accurate as the classical fit on the same sessions
    for p in ("b1", "b2"):
        assert e[f"map/{p}"]["rms_error"] < 1.5 * e[f"classical/{p}"]["rms_error"]
    rows = (tmp_path / "validation.csv").read_text().splitlines()
    assert len(rows) == 7
    assert json.loads((tmp_path / "validation.json").read_text())["all"]["n_sessions"] == 6
    assert (tmp_path / "coverage.png").stat().st_size > 1000
    assert "map/b1" in format_summary(e)
    assert np.isfinite(e["map/b1"]["rms_error"])
