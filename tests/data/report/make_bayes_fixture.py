"""Regenerate ``bayes_result.json``: a hand-made Bayesian result for the certificate tests.

Built on the classical result of the simulated session (``chekan simulate``, seed 0),
with the keys the Bayesian method adds: HDI and R-hat/ESS per parameter, the
uncertainty budget of b, diagnostics, the posterior-predictive band of δg and the
drift curve. The numbers are plausible, not computed. The NetCDF (``posterior.nc``)
is made by the tests with ArviZ (``write_posterior_netcdf`` below).

    .venv/bin/python tests/data/report/make_bayes_fixture.py /tmp/sim.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

# posterior means and sds of the NetCDF draws (also the JSON's parameters)
POSTERIOR = {
    "b1": (6.980412, 0.000105),
    "b2": (6.882133, 0.000110),
    "a": (1.3950e-4, 1.1e-6),
    "eps1_arcmin": (4.012, 0.041),
    "eps2_arcmin": (-2.987, 0.043),
    "dgamma_arcmin": (7.91, 0.62),
    "tau_s": (29.6, 1.8),
}


def write_posterior_netcdf(path: str | Path, draws: int = 250, seed: int = 7) -> Path:
    """A tiny ArviZ posterior (2 chains) with the variables the certificate plots."""
    import arviz as az

    rng = np.random.default_rng(seed)
    z = rng.standard_normal((2, draws))
    post = {}
    for k, (m, s) in POSTERIOR.items():
        e = rng.standard_normal((2, draws))
        post[k] = m + s * (0.6 * z + 0.8 * e if k in ("b1", "a") else e)  # b1 and a correlate
    az.from_dict(posterior=post).to_netcdf(str(path))
    return Path(path)


def _entry(mean: float, sd: float, unit: str, r_hat: float, ess: float) -> dict:
    return {
        "mean": mean,
        "sd": sd,
        "hdi_low": mean - 1.96 * sd,
        "hdi_high": mean + 1.96 * sd,
        "unit": unit,
        "r_hat": r_hat,
        "ess_bulk": ess,
    }


def make(classical: dict) -> dict:
    res = json.loads(json.dumps(classical))
    res["serial"] = 'B-7 #1 $x* "q"'  # typst/HTML special characters on purpose
    res["method"] = "bayes"
    res["record"] = "archive/missing_record.csv"  # archived: the record is not at hand
    res["record_sha256"] = "0" * 63 + "1"
    res["metadata"] = dict(res.get("metadata", {}))
    res["metadata"]["site"] = 'Lab #3 $1_000 *roof* \\ "north"'
    res["posterior_netcdf"] = "posterior.nc"
    res.pop("fixed", None)
    units = {
        "b1": "mGal/pix",
        "b2": "mGal/pix",
        "a": "mGal/pix^2",
        "eps1_arcmin": "arcmin",
        "eps2_arcmin": "arcmin",
        "dgamma_arcmin": "arcmin",
        "tau_s": "s",
    }
    p: dict[str, dict] = {}
    for i, (k, (m, s)) in enumerate(POSTERIOR.items()):
        p[k] = _entry(m, s, units[k], 1.001 + 0.0005 * i, 950.0 - 40 * i)
    mh = res["level_reading_pix"]
    for s in (1, 2):
        b, sd = POSTERIOR[f"b{s}"]
        p[f"b{s}_0"] = _entry(
            b + 2 * POSTERIOR["a"][0] * (1024.0 - mh[f"m{s}"]), sd, "mGal/pix", 1.002, 900.0
        )
    p["drift1_pix_per_h"] = _entry(0.041, 0.006, "pix/h", 1.003, 812.0)
    p["drift2_pix_per_h"] = _entry(-0.029, 0.006, "pix/h", 1.002, 830.0)
    p["sigma_theta_arcsec"] = _entry(2.1, 0.4, "arcsec", 1.004, 845.0)
    p["sigma_hold_pix"] = _entry(0.081, 0.012, "pix", 1.003, 870.0)
    res["parameters"] = p
    res["uncertainty_budget"] = {
        "b1": {
            "angle_readout": 9.1e-5,
            "noise": 4.0e-5,
            "drift": 2.5e-5,
            "a": 1.2e-5,
            "total": 1.05e-4,
            "expanded_k2": 2.1e-4,
        },
        "b2": {
            "angle_readout": 9.4e-5,
            "noise": 4.4e-5,
            "drift": 2.9e-5,
            "a": 1.3e-5,
            "total": 1.10e-4,
            "expanded_k2": 2.2e-4,
        },
    }
    res["instability_percent"] = {
        "b1": (p["b1"]["mean"] - res["b_prior"]["b1"]) / res["b_prior"]["b1"] * 100,
        "b2": (p["b2"]["mean"] - res["b_prior"]["b2"]) / res["b_prior"]["b2"] * 100,
    }
    res["diagnostics"] = {
        "converged": True,
        "r_hat_max": 1.004,
        "ess_bulk_min": 812.0,
        "problems": ["tau_s is weakly identified: its posterior is close to the prior"],
        "n_draws": 4000,
        "seconds": 41.7,
    }
    rs = res["residuals_mgal"]
    cols = rs["columns"]
    res["posterior_predictive_mgal"] = {
        "columns": cols,
        "delta_g_mean": {
            c: [0.05 * np.sin(i) for i in range(len(rs["angle_label"]))] for c in cols
        },
        "delta_g_low": {c: [-0.9 - 0.02 * i for i in range(len(rs["angle_label"]))] for c in cols},
        "delta_g_high": {c: [0.9 + 0.02 * i for i in range(len(rs["angle_label"]))] for c in cols},
    }
    t = np.linspace(0.0, 9.0, 37)
    d1 = 0.041 * t + 0.002 * t**2
    d2 = -0.029 * t + 0.001 * t**2
    res["drift_curve"] = {
        "t_h": t.tolist(),
        "m1_pix": d1.tolist(),
        "m1_low": (d1 - 0.05 - 0.01 * t).tolist(),
        "m1_high": (d1 + 0.05 + 0.01 * t).tolist(),
        "m2_pix": d2.tolist(),
        "m2_low": (d2 - 0.05 - 0.01 * t).tolist(),
        "m2_high": (d2 + 0.05 + 0.01 * t).tolist(),
    }
    return res


if __name__ == "__main__":
    src = json.loads(Path(sys.argv[1]).read_text(encoding="utf-8"))
    out = HERE / "bayes_result.json"
    out.write_text(json.dumps(make(src), indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    print(f"wrote {out}")
