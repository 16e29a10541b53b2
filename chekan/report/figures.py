"""The figures of the certificate (matplotlib, object API: no pyplot, no global state).

Each function returns PNG bytes. ``t`` is the translator of :mod:`chekan.report.i18n`.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np

from chekan.classical.settling import fitted_model, model_at_holds
from chekan.report.i18n import Translator, param_name
from chekan.report.plotting import new_figure

DPI = 200
SYS_COLORS = ("#1f62b4", "#c8382c")
ROUND_MARKERS = ("o", "s", "^", "D", "v", "P")
RC = {
    "font.size": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "axes.linewidth": 0.6,
    "legend.fontsize": 7,
    "legend.framealpha": 0.85,
    "axes.formatter.useoffset": False,
}
PAIR_VARS = ("b1", "b2", "a", "eps1_arcmin", "eps2_arcmin", "dgamma_arcmin")


def round_labels(rounds: Sequence[int], t: Translator, system: int) -> dict[int, str | None]:
    """The legend label of each round's markers for ``system`` (0-based): one per round
    while every round has a marker of its own; past :data:`ROUND_MARKERS` the markers
    repeat, so one label names the rounds together (a legend of 40 entries squashed the
    axes of a 20-round certificate). Round 0 is the level holds."""
    tilt = sorted(int(r) for r in set(rounds) if r)
    sys_part = f", {t('lg_s', n=system + 1)}"
    out: dict[int, str | None] = {0: t("lg_level") + sys_part} if 0 in set(rounds) else {}
    if len(tilt) <= len(ROUND_MARKERS):
        return out | {r: t("lg_round", n=r) + sys_part for r in tilt}
    together = t("lg_rounds", a=tilt[0], b=tilt[-1]) + sys_part
    return out | {r: together if k == 0 else None for k, r in enumerate(tilt)}


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def _rc():
    import matplotlib

    return matplotlib.rc_context(cast(Any, RC))  # its stubs list every key as a literal


def record_figure(record: Any, holds: Any, t: Translator) -> bytes:
    """Readings of both systems and the platform tilt over time, with the holds shaded."""
    th = np.asarray(record.t_s, dtype=float) / 3600.0
    stride = max(1, th.size // 8000)
    sl = slice(None, None, stride)
    with _rc():
        fig = new_figure((7.0, 4.4), constrained=True)
        ax1, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
        for s, m in enumerate((record.m1_pix, record.m2_pix)):
            ax1.plot(
                th[sl], np.asarray(m)[sl], lw=0.6, color=SYS_COLORS[s], label=t("lg_s", n=s + 1)
            )
        ax2.plot(
            th[sl],
            np.asarray(record.tilt_x_arcsec)[sl] / 3600.0,
            lw=0.7,
            color="#444444",
            label=t("lg_tilt_x"),
        )
        ax2.plot(
            th[sl],
            np.asarray(record.tilt_y_arcsec)[sl] / 3600.0,
            lw=0.7,
            color="#2a9d4b",
            label=t("lg_tilt_y"),
        )
        for i in range(holds.n):
            t0, t1 = holds.t_start_s[i] / 3600.0, holds.t_end_s[i] / 3600.0
            ts = min(t1, t0 + holds.settle_s / 3600.0)
            color = "#4a7fd0" if holds.is_level[i] else "#f0a030"
            for ax in (ax1, ax2):
                ax.axvspan(t0, ts, color=color, alpha=0.07, lw=0)
                ax.axvspan(ts, t1, color=color, alpha=0.2, lw=0)
        ax1.set_ylabel(t("ax_reading"))
        ax2.set_ylabel(t("ax_tilt"))
        ax2.set_xlabel(t("ax_time_h"))
        ax1.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=2, frameon=False)
        ax2.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=2, frameon=False)
        ax2.set_xlim(th[0], th[-1])
        return _png(fig)


ARCSEC_RAD = np.pi / 648000.0


def _readings(params, axis, theta_rad: np.ndarray, other_rad: np.ndarray) -> np.ndarray:
    """The model's readings (n, 2) at the signed angle θ about ``axis`` ("x"/"y", or one
    per point), the other axis at ``other_rad``."""
    from chekan.physics import sensor as model

    about_y = np.asarray(axis) == "y"
    tx = np.where(about_y, other_rad, theta_rad)
    ty = np.where(about_y, theta_rad, other_rad)
    return model.equilibrium_readings_host(params, tx, ty)


def hold_axes(holds: Any) -> np.ndarray:
    """The axis of every hold ("x"/"y"): ``holds.hold_axis``, or the table's one axis."""
    per = np.asarray(getattr(holds, "hold_axis", ()), dtype=str)
    if per.size == holds.n:
        return per
    return np.full(holds.n, "x" if holds.axis == "x" else "y")


def has_noise_model(result: Mapping[str, Any]) -> bool:
    """True when the result states σ_hold and σ_θ (the joint model's noise of a hold mean)."""
    p = result["parameters"]
    return "sigma_hold_pix" in p and "sigma_theta_arcsec" in p


def residual_band_pix(
    result: Mapping[str, Any], params, holds: Any, resid: np.ndarray
) -> np.ndarray:
    """Half-width (n, 2) of the 95 % band of a hold mean about the model, pix.

    Joint results: 2·√(σ_hold² + (∂m/∂θ·σ_θ)²), the model's scatter of a hold mean (a hold
    offset and the angle's random readout); classical: 2·RMS of the residuals per system.
    """
    if not has_noise_model(result):
        rms = np.sqrt(np.nanmean(resid[~holds.is_level] ** 2, axis=0))
        return np.broadcast_to(2.0 * rms, resid.shape).copy()
    p = result["parameters"]
    s_hold = float(p["sigma_hold_pix"]["mean"])
    s_theta = float(p["sigma_theta_arcsec"]["mean"]) * ARCSEC_RAD
    theta = np.asarray(holds.theta_rad, dtype=float)
    axes = hold_axes(holds)
    tx, ty = (np.asarray(a, dtype=float) for a in (holds.tilt_x_rad, holds.tilt_y_rad))
    other = np.where(axes == "y", tx, ty)
    h = 1e-5
    slope = (
        _readings(params, axes, theta + h, other) - _readings(params, axes, theta - h, other)
    ) / (2 * h)
    return 2.0 * np.sqrt(s_hold**2 + (slope * s_theta) ** 2)


def cosinusoid_figure(
    holds: Any, result: Mapping[str, Any], t: Translator, transient: np.ndarray | None = None
) -> bytes | None:
    """Hold means against the signed tilt angle θ (Fig. 3 of the paper) with the fitted
    model's readings; below, each hold mean minus the model's reading at the angles measured
    in that hold (plus ``transient``, what the lag leaves in each hold mean:
    :func:`chekan.classical.settling.unsettled_transient_pix`), with the model's 95 % band. None
    when
    the result has no model (a ≤ 0)."""
    params = fitted_model(result)
    if params is None:
        return None
    theta = np.asarray(holds.theta_rad, dtype=float)
    expected = model_at_holds(params, holds)
    if transient is not None:
        expected = expected + transient
    resid = np.asarray(holds.m_mean_pix, dtype=float) - expected
    band = residual_band_pix(result, params, holds, resid)
    theta_deg = np.rad2deg(theta)
    lim = float(np.nanmax(np.abs(theta_deg))) * 1.05 if theta.size else 6.0
    grid = np.linspace(-lim, lim, 401)
    axes = hold_axes(holds)
    tilt_axes = sorted(set(axes[~np.asarray(holds.is_level)]), reverse=True) or ["y"]
    curves = {a: _readings(params, a, np.deg2rad(grid), np.zeros_like(grid)) for a in tilt_axes}
    order = np.argsort(theta_deg, kind="stable")
    rounds = np.asarray(holds.round)
    with _rc():
        fig = new_figure((7.0, 4.8), constrained=True)
        ax1, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2.0, 1.2]})
        for s in range(2):
            col = SYS_COLORS[s]
            for a, curve in curves.items():
                ls = "-" if a == "y" else "--"
                ax1.plot(grid, curve[:, s], color=col, lw=0.8, alpha=0.7, ls=ls)
            ax2.fill_between(
                theta_deg[order], -band[order, s], band[order, s], color=col, alpha=0.12, lw=0
            )
            labels = round_labels(rounds.tolist(), t, s)
            for r in np.unique(rounds):
                sel = rounds == r
                mk = "x" if r == 0 else ROUND_MARKERS[(r - 1) % len(ROUND_MARKERS)]
                label = labels[int(r)]
                style = dict(ls="none", marker=mk, ms=3.5, mfc="none", mew=0.8, color=col)
                ax1.plot(theta_deg[sel], holds.m_mean_pix[sel, s], label=label, **style)
                ax2.plot(theta_deg[sel], resid[sel, s], **style)
        if len(curves) > 1:  # rounds about both axes: one model curve per axis
            for a in curves:
                ls = "-" if a == "y" else "--"
                ax1.plot(
                    [], [], color="0.3", lw=0.8, ls=ls, label=t("lg_model_axis", axis=a.upper())
                )
        else:
            ax1.plot([], [], color="0.3", lw=0.8, label=t("lg_model"))
        band_label = t("lg_model_band" if has_noise_model(result) else "lg_rms_band")
        ax2.fill_between([], [], [], color="0.5", alpha=0.3, label=band_label)
        ax1.set_ylabel(t("ax_reading"))
        ax2.set_ylabel(t("ax_resid_pix"))
        ax2.set_xlabel(t("ax_angle"))
        ax2.axhline(0.0, color="0.3", lw=0.6)
        ax1.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=6.5)
        ax2.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=6.5)
        return _png(fig)


def residual_figure(
    residuals: Mapping[str, Any],
    t: Translator,
    *,
    tol_mgal: float | None,
    band: Mapping[str, Any] | None = None,
) -> bytes:
    """δg per angle for every column (round × system), their mean, bands and the tolerance."""
    labels = list(residuals["angle_label"])
    cols = list(residuals["columns"])
    x = np.arange(len(labels), dtype=float)
    offs = np.linspace(-0.27, 0.27, len(cols)) if len(cols) > 1 else np.zeros(1)
    col_round = {c: _round_of(c) for c in cols}
    legend = [round_labels(list(col_round.values()), t, s) for s in range(2)]
    with _rc():
        fig = new_figure((7.0, 3.4), constrained=True)
        ax = fig.subplots()
        for j, c in enumerate(cols):
            s = 1 if c.endswith("s2") else 0
            r = col_round[c]
            mk = ROUND_MARKERS[(r - 1) % len(ROUND_MARKERS)]
            y = np.asarray(residuals["delta_g_mgal"][c], dtype=float)
            if band is not None and c in band.get("delta_g_low", {}):
                lo = np.asarray(band["delta_g_low"][c], dtype=float)
                hi = np.asarray(band["delta_g_high"][c], dtype=float)
                ax.vlines(x + offs[j], lo, hi, color=SYS_COLORS[s], lw=4, alpha=0.25)
                if c in band.get("delta_g_mean", {}):
                    ax.plot(
                        x + offs[j],
                        band["delta_g_mean"][c],
                        ls="none",
                        marker="_",
                        ms=7,
                        color=SYS_COLORS[s],
                        alpha=0.8,
                    )
            ax.plot(
                x + offs[j],
                y,
                ls="none",
                marker=mk,
                ms=4,
                mfc="none",
                mew=0.9,
                color=SYS_COLORS[s],
                label=legend[s][r],
            )
        ax.plot(
            x,
            residuals["mean_delta_g_mgal"],
            color="black",
            lw=1.0,
            marker="o",
            ms=3,
            label=t("lg_mean"),
        )
        if band is not None:
            ax.vlines([], [], [], color="0.5", lw=4, alpha=0.3, label=t("lg_band"))
        if tol_mgal is not None:
            for sgn in (1, -1):
                ax.axhline(
                    sgn * tol_mgal,
                    color="#b03030",
                    ls="--",
                    lw=0.8,
                    label=t("lg_tol") if sgn > 0 else None,
                )
        ax.axhline(0.0, color="0.4", lw=0.5)
        ax.set_xticks(x, labels)
        ax.set_xlabel(t("ax_angle"))
        ax.set_ylabel(t("ax_dg"))
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=6.5)
        return _png(fig)


def _round_of(column: str) -> int:
    """The round of a column ``r<round>_s<system>`` (1 if it names none)."""
    try:
        return int(column.split("_")[0].lstrip("r"))
    except ValueError:
        return 1


def read_posterior(path: str | Path, names: Sequence[str] = PAIR_VARS) -> dict[str, np.ndarray]:
    """Flattened draws of ``names`` (those present) from the posterior group of a NetCDF."""
    import xarray as xr

    try:
        ds = xr.open_dataset(path, group="posterior", engine="h5netcdf")
    except (OSError, ValueError):  # not HDF5-based or no engine: let ArviZ try
        import arviz as az

        ds = az.from_netcdf(path).posterior
    with ds:
        return {
            n: np.asarray(ds[n].values, dtype=float).reshape(-1)
            for n in names
            if n in ds and set(ds[n].dims) <= {"chain", "draw"}  # scalar parameters only
        }


def pair_figure(draws: Mapping[str, np.ndarray], lang: str, *, max_points: int = 1500) -> bytes:
    """Corner plot: marginal histograms on the diagonal, scatter of draws below it."""
    from matplotlib.ticker import MaxNLocator

    names = list(draws)
    k = len(names)
    n = min(len(v) for v in draws.values())
    idx = np.linspace(0, n - 1, min(n, max_points)).astype(int)
    size = 1.25 * k + 0.6
    with _rc():
        fig = new_figure((min(size, 7.0), min(size, 7.0)))  # unconstrained: fast for k² axes
        fig.subplots_adjust(left=0.11, bottom=0.11, right=0.98, top=0.98, wspace=0.12, hspace=0.12)
        axes = fig.subplots(k, k, squeeze=False)
        for i in range(k):
            yi = draws[names[i]]
            for j in range(k):
                ax = axes[i, j]
                if j > i:
                    ax.set_axis_off()
                    continue
                xj = draws[names[j]]
                ax.xaxis.set_major_locator(MaxNLocator(3))
                ax.yaxis.set_major_locator(MaxNLocator(3))
                ax.tick_params(labelsize=5.5)
                if i == j:
                    ax.hist(xj, bins=30, color="#4a7fd0", alpha=0.8)
                    ax.tick_params(axis="y", left=False, labelleft=False)
                    ax.grid(False, axis="y")
                else:
                    ax.plot(
                        xj[idx], yi[idx], ls="none", marker=".", ms=1.5, alpha=0.35, color="#1f3f7a"
                    )
                if i == k - 1:
                    ax.set_xlabel(param_name(names[j], lang), fontsize=8)
                    ax.tick_params(axis="x", labelrotation=45)
                else:
                    ax.tick_params(axis="x", labelbottom=False)
                if j == 0 and i > 0:
                    ax.set_ylabel(param_name(names[i], lang), fontsize=8)
                elif i != j:
                    ax.tick_params(axis="y", labelleft=False)
        return _png(fig)


def drift_figure(curve: Mapping[str, Sequence[float]], t: Translator) -> bytes:
    """The estimated drift of both systems over time with its band."""
    th = np.asarray(curve["t_h"], dtype=float)
    with _rc():
        fig = new_figure((7.0, 2.8), constrained=True)
        ax = fig.subplots()
        for s in range(2):
            key = f"m{s + 1}"
            if f"{key}_pix" not in curve:
                continue
            col = SYS_COLORS[s]
            if f"{key}_low" in curve and f"{key}_high" in curve:
                ax.fill_between(
                    th, curve[f"{key}_low"], curve[f"{key}_high"], color=col, alpha=0.2, lw=0
                )
            ax.plot(th, curve[f"{key}_pix"], color=col, lw=1.0, label=t("lg_s", n=s + 1))
        ax.set_xlabel(t("ax_time_h"))
        ax.set_ylabel(t("ax_drift"))
        ax.legend(loc="best")
        return _png(fig)
