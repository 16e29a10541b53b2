"""The posterior NetCDF written directly (inference.arviz_io.save_posterior_netcdf) reads back
as the file ArviZ writes from the same arrays."""

from __future__ import annotations

import numpy as np

from inference.arviz_io import (
    load_netcdf,
    save_netcdf,
    save_posterior_netcdf,
    to_inference_data,
)


def test_direct_netcdf_reads_back_as_arviz_writes_it(tmp_path) -> None:
    rng = np.random.default_rng(0)
    C, D, H = 4, 50, 6
    post = {
        "b1": rng.random((C, D)),
        "angle_error_arcsec": rng.random((C, D, H)),
        "hold_offset_pix": rng.random((C, D, H, 2)),
        "drift_coeffs": rng.random((C, D, 2, 3)),
        "unnamed": rng.random((C, D, 3)),
    }
    y = rng.random((9, 2))
    y[2, 1] = np.nan
    groups = {
        "posterior": post,
        "posterior_predictive": {"delta_g_mgal": rng.random((1, 20, 4, 8))},
        "log_likelihood": {"bin_mean_pix": rng.random((C, D, 9, 2))},
        "sample_stats": {"lp": rng.random((C, D))},
        "observed_data": {"bin_mean_pix": y},
    }
    kw = {
        "coords": {"hold": [3, 5, 7, 9, 11, 13], "system": [1, 2], "column": ["a", "bb", "c", "d"]},
        "dims": {
            "angle_error_arcsec": ["hold"],
            "hold_offset_pix": ["hold", "system"],
            "drift_coeffs": ["system", "degree"],
            "bin_mean_pix": ["bin", "system"],
            "delta_g_mgal": ["column", "angle"],
        },
        "attrs": {"model": "chekan.joint", "draws": f"{C}×{D}"},
    }
    idata = to_inference_data(post, **{g: v for g, v in groups.items() if g != "posterior"}, **kw)
    a = load_netcdf(save_netcdf(idata, tmp_path / "arviz.nc"))
    b = load_netcdf(save_posterior_netcdf(tmp_path / "direct.nc", groups, **kw))
    assert a.groups() == b.groups()
    for g in a.groups():
        da, db = a[g], b[g]
        assert dict(da.sizes) == dict(db.sizes), g
        assert set(da.variables) == set(db.variables), g
        for v in da.variables:
            assert da[v].dims == db[v].dims, (g, v)
            assert da[v].dtype == db[v].dtype, (g, v)
            np.testing.assert_array_equal(da[v].values, db[v].values)
        drop = {"created_at"}
        assert {k: x for k, x in da.attrs.items() if k not in drop} == {
            k: x for k, x in db.attrs.items() if k not in drop
        }, g
    assert not list(tmp_path.glob(".*.tmp"))


def test_direct_netcdf_refuses_before_writing_without_room(tmp_path, monkeypatch) -> None:
    import shutil
    from collections import namedtuple

    import pytest

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(1, 1, 1000))
    with pytest.raises(OSError, match="no room for the posterior") as e:
        save_posterior_netcdf(tmp_path / "post.nc", {"posterior": {"x": np.zeros((2, 1000))}})
    assert e.value.errno == 28 and list(tmp_path.iterdir()) == []
