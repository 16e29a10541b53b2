"""Padded models (records of similar size share one compiled solver) and the MAP of many
records in re-analysis, one at a time, a bad one failing alone."""

from __future__ import annotations

import numpy as np
import pytest

from chekan import joint
from chekan.fit import initial_values
from chekan.joint.beta_posterior import solve_beta
from chekan.pipeline import CalibrationOptions, calibrate_file


def test_pad_model_is_exact(short_session) -> None:
    """Padded bins, holds and slew samples add nothing to the residuals."""
    import jax.numpy as jnp

    from chekan.classical.fit import calibrate_record

    _, rec, _ = short_session
    opts = CalibrationOptions(method="map", progress=False)
    cres, _ = calibrate_record(rec, settle_s=opts.settle_s)
    _, model = joint.prepare(rec, opts.settle_s)
    padded = model.pad(model.n_holds + 3, model.n_bins + 5, 40)
    assert padded.n_beta == model.n_beta + 9  # 3 holds × (o₁, o₂, δ)
    v = {k: jnp.asarray(x) for k, x in initial_values(cres, rec.g_local_mgal).items()}
    h = joint.default_hyper(noise_scale=(1.2, 0.8), slew_error=0.01)
    rw, beta, _, _ = solve_beta(v, h, model.structure, model.data)
    rw_p, beta_p, _, _ = solve_beta(v, h, padded.structure, padded.data)
    N = model.n_bins
    np.testing.assert_allclose(np.asarray(rw_p)[: 2 * N], np.asarray(rw), rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(rw_p)[2 * N :], 0.0)
    for name in ("c", "drift", "angle_error"):
        got = np.asarray(beta_p)[padded.beta_blocks[name]]
        want = np.asarray(beta)[model.beta_blocks[name]]
        np.testing.assert_allclose(got[: want.size], want, rtol=1e-8, atol=1e-12)
        np.testing.assert_array_equal(got[want.size :], 0.0)
    with pytest.raises(ValueError, match="cannot pad"):
        model.pad(model.n_holds - 1, model.n_bins, 40)


@pytest.mark.slow
def test_map_of_many_equals_one_by_one(short_program, short_session, tmp_path) -> None:
    from chekan.archive.reanalyze import solve_many_map
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session

    path7, _, _ = short_session
    rec8, _ = simulate_session(short_program, Truth(serial="T-2", b_mgal_per_pix=(6.95, 6.91)), 8)
    path8 = tmp_path / "rec8.csv"
    write_record(path8, rec8)
    broken = tmp_path / "broken.csv"
    broken.write_text(path7.read_text(encoding="utf-8").replace("\n", "\nnot,a,row\n", 30)[:5000])
    opts = CalibrationOptions(method="map", progress=False)
    many = solve_many_map([path7, broken, path8], opts)
    assert isinstance(many[1], Exception) and "broken.csv" in str(many[1])
    for path, got in ((path7, many[0]), (path8, many[2])):
        want = calibrate_file(path, opts)
        assert got["diagnostics"]["converged"], got["diagnostics"]["problems"]
        for p in ("b1", "b2", "a", "eps1_arcmin", "tau_s"):
            g, w = got["parameters"][p], want["parameters"][p]
            assert abs(g["mean"] - w["mean"]) < 1e-9 * w["sd"], (path.name, p)
            assert g["sd"] == pytest.approx(w["sd"], rel=1e-9), (path.name, p)
