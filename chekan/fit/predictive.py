"""What a posterior gives beyond its parameter table: the posterior predictive of the
paper's δg table, the drift curve, and the ArviZ NetCDF."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from chekan.classical.fit import fit_by_axis, increments_of_readings
from chekan.joint.derived import equilibria_of
from chekan.joint.problem import K_DESIGN
from chekan.physics import sensor as fm
from chekan.physics.units import ARCMIN_PER_RAD, ARCSEC_PER_RAD
from chekan.runtime import jit
from chekan.runtime.engine import engine_for


def posterior_predictive_delta_g(holds, g_local, draws: dict, model, rng, a_fixed=None, n_max=200):
    """Replicate the settled hold means from posterior draws and redo the classical δg.

    For each draw: ŷₖⱼ = Eₖⱼ(θ) + cⱼ + driftⱼ(tₖ) + õₖⱼ − Sₖⱼ δ̃ₖ + noise/√nₖ with fresh
    hold offsets and angle errors (a replicated session), then pairs, level
    interpolation and the least squares of eq. (21) exactly as the classical method (whose
    table is the rounds about Y where a record has both axes).
    """
    n = draws["b1"].size
    take = rng.choice(n, size=min(n, n_max), replace=False)
    flat = {k: np.asarray(v).reshape(n, *np.asarray(v).shape[2:]) for k, v in draws.items()}
    t0, t1 = model.t_span_s
    s = 2.0 * (holds.t_mid_s - t0) / max(t1 - t0, 1.0) - 1.0
    P = np.polynomial.legendre.legvander(np.nan_to_num(s), model.drift_degree)[:, 1:]
    g = float(g_local)
    compiled = engine_for(model.structure).predictive
    m0 = float(np.asarray(model.data.m0))  # the record's CCD centre, as the fit uses it
    # one executable per bucket: the draws padded to n_max, the holds to the bucket's
    shape = (n_max, max(model.structure.n_holds, len(holds.tilt_y_rad)))
    E_all, S_all = _equilibria(g, m0, flat, take, holds, compiled, shape)  # (draws, K, 2)
    ys = []
    for n_draw, i in enumerate(take):
        E, S = E_all[n_draw], S_all[n_draw]
        drift = P @ flat["drift_coeffs"][i].T
        o = rng.normal(0, flat["sigma_hold_pix"][i], E.shape)
        d = rng.normal(0, flat["sigma_theta_arcsec"][i], E.shape[0]) / ARCSEC_PER_RAD
        noise = rng.normal(0, 1, E.shape) * np.array([flat["sigma1_pix"][i], flat["sigma2_pix"][i]])
        root_n = np.sqrt(np.maximum(holds.n_used, 1))[:, None]
        ys.append(E + drift + o - S * d[:, None] + noise / root_n)
    # as the classical method reports it: the rounds about Y (the X rounds' own fit is not
    # in the table)
    tables = increments_of_readings(holds, g, np.stack(ys))
    # (draws, R, 2, n)
    fits = (fit_by_axis(t, a_fixed=a_fixed, x_apart=False) for t in tables)
    return np.stack([f.delta_g_mgal for f in fits])


def _equilibria(
    g: float,
    m0: float,
    flat: dict,
    take,
    holds,
    compiled: Callable | None = None,
    shape: tuple[int, int] | None = None,
):
    """E and ∂E/∂θ at the hold attitudes for the draws ``take`` (CCD centre ``m0`` pix), in one
    vectorised call (a loop over draws dispatched two jitted calls and built parameters per
    draw).
    ``compiled``: :func:`equilibria_of` as the engine keeps it (a new process then loads it
    instead of tracing the vmapped model, ≈ 1.2 s); else jitted here. ``shape`` (draws,
    holds): the call padded to it (the last draw repeated, level holds added) and cut back,
    so that records of one bucket share one executable."""
    n_take, n_holds = len(take), len(holds.tilt_y_rad)
    if shape is not None:
        take = np.concatenate([take, np.full(shape[0] - n_take, take[-1])])
    a = flat["a"][take]
    K = np.where(a > 0, fm.K_from_a(np.where(a > 0, a, 1.0), g), K_DESIGN)
    n = len(take)
    fields = {
        "g_mgal": np.full(n, g),
        "K_pix_per_rad": K,
        "m0_pix": np.full(n, m0),
        "b_mgal_per_pix": np.stack([flat["b1"][take], flat["b2"][take]], axis=1),
        "m_level_pix": flat["m_level_pix"][take],
        "eps_rad": np.stack([flat["eps1_arcmin"][take], flat["eps2_arcmin"][take]], axis=1)
        / ARCMIN_PER_RAD,
        "gamma_rad": flat["dgamma_arcmin"][take] / ARCMIN_PER_RAD,
    }
    sp = fm.SensorParams(**{k: jnp.asarray(v, dtype=jnp.float64) for k, v in fields.items()})
    tx, ty = np.asarray(holds.tilt_x_rad, float), np.asarray(holds.tilt_y_rad, float)
    if shape is not None:
        tx, ty = (np.pad(t, (0, shape[1] - n_holds)) for t in (tx, ty))
    fn = _equilibria_jit if compiled is None else compiled
    E, S = fn(sp, tx, ty)
    return np.asarray(E)[:n_take, :n_holds], np.asarray(S)[:n_take, :n_holds]


_equilibria_jit = jit(equilibria_of)


def drift_curve(draws, model, hp: float, n: int = 60) -> dict:
    t0, t1 = model.t_span_s
    t = np.linspace(t0, t1, n)
    s = 2.0 * (t - t0) / max(t1 - t0, 1.0) - 1.0
    P = np.polynomial.legendre.legvander(s, model.drift_degree)[:, 1:]
    P0 = np.polynomial.legendre.legvander(np.array([-1.0]), model.drift_degree)[:, 1:]
    dr = draws["drift_coeffs"].reshape(-1, 2, model.drift_degree)
    curves = np.einsum("tk,djk->dtj", P - P0, dr)  # relative to the start
    lo, hi = (1 - hp) / 2 * 100, (1 + hp) / 2 * 100
    out = {"t_h": list((t - t0) / 3600.0)}
    for j in range(2):
        out[f"m{j + 1}_pix"] = list(curves[:, :, j].mean(axis=0))
        out[f"m{j + 1}_low"] = list(np.percentile(curves[:, :, j], lo, axis=0))
        out[f"m{j + 1}_high"] = list(np.percentile(curves[:, :, j], hi, axis=0))
    return out


def write_netcdf(path, draws, samp, model, rep, cols) -> Path:
    """The ArviZ NetCDF of the posterior (:func:`inference.arviz_io.save_posterior_netcdf`:
    the InferenceData layout written without importing ArviZ or xarray)."""
    from chekan.files.durable import fsync_dir
    from inference.arviz_io import save_posterior_netcdf

    C, Dn = samp.draws.shape[:2]
    post = dict(draws.quantities)  # draws: chekan.fit.reported.ReportedDraws
    n_bins = model.n_real_bins  # the record's bins, not its bucket's padding
    y = np.asarray(model.data.y)[:n_bins]
    mask = np.asarray(model.data.mask)[:n_bins]
    nrep = rep.shape[0]
    groups = {
        "posterior": post,
        "posterior_predictive": {
            "delta_g_mgal": np.broadcast_to(
                rep.reshape(1, nrep, len(cols) // 2, 2, -1).reshape(1, nrep, len(cols), -1),
                (1, nrep, len(cols), rep.shape[-1]),
            )
        },
        "log_likelihood": {"bin_mean_pix": draws.loglik},
        "sample_stats": {"lp": samp.log_prob},
        "observed_data": {"bin_mean_pix": np.where(mask, y, np.nan)},
    }
    return save_posterior_netcdf(
        path,
        groups,
        coords={"hold": [int(s) for s in model.hold_steps], "system": [1, 2], "column": cols},
        dims={
            "angle_error_arcsec": ["hold"],
            "hold_offset_pix": ["hold", "system"],
            "m_level_pix": ["system"],
            "drift_coeffs": ["system", "degree"],
            "bin_mean_pix": ["bin", "system"],
            "delta_g_mgal": ["column", "angle"],
        },
        attrs={"model": "chekan.joint", "draws": f"{C}×{Dn}"},
        sync_dir=fsync_dir,
    )
