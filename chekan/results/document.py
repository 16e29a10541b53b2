"""The ``chekan-result/1`` JSON (``results-json.md``): build, write, read and check.

Every method writes the fixed keys of the spec; extra keys are ours. A method that
does not estimate a parameter leaves its key out (``a`` fixed → ``fixed.a``).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
from collections.abc import Mapping
from pathlib import Path
from statistics import NormalDist
from typing import TYPE_CHECKING, Any

import numpy as np

import chekan
from chekan.errors import FormatError
from chekan.options import METHODS
from chekan.physics.parameters import PARAMETER_UNITS
from chekan.records.holds import gaps_entry
from chekan.records.reader import Record

if TYPE_CHECKING:
    from chekan.classical.fit import ClassicalFit
    from chekan.classical.settling import Settling
    from chekan.options import CalibrationOptions
    from chekan.records.inputs import ReadyInput

FORMAT = "chekan-result/1"
REQUIRED_KEYS = ("format", "serial", "record", "method", "g_local_mgal", "parameters")
PARAM_FIELDS = ("mean", "sd", "hdi_low", "hdi_high")
UNITS = PARAMETER_UNITS  # one table: chekan.physics.parameters
META_KEYS = (
    "instrument",
    "model",
    "platform_serial",
    "site",
    "started",
    "date",
    "latitude_deg",
    "longitude_deg",
    "height_m",
    "operator",
    "program",
)


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def z_for(prob: float) -> float:
    """Two-sided standard-normal quantile: P(|Z| < z) = prob.

    The standard library's inverse (Wichura's AS 241, equal to ``scipy.special.ndtri`` within
    2 ulp) spares every new process the 0.2–0.7 s import of ``scipy.special``.
    """
    return NormalDist().inv_cdf(0.5 + prob / 2.0)


def param_entry(
    mean: float,
    sd: float | None,
    hdi_prob: float,
    unit: str = "",
    *,
    nu_eff: float | None = None,
    **extra,
) -> dict:
    """A parameter entry of a least-squares method: :func:`interval_entry` with k the normal
    quantile :func:`z_for`, or Student's t with the sd's effective degrees of freedom
    ``nu_eff`` (then stored as ``nu_eff``: GUM G.4, :mod:`inference.dof`)."""
    if nu_eff is not None and np.isfinite(nu_eff):
        from inference.dof import coverage_factor

        k = coverage_factor(float(nu_eff), hdi_prob)
        extra = {**extra, "nu_eff": float(nu_eff)}
    else:
        k = z_for(hdi_prob)
    return interval_entry(mean, sd, k, unit, **extra)


def interval_entry(mean: float, sd: float | None, k: float, unit: str = "", **extra) -> dict:
    """A parameter entry with the symmetric interval mean ± k·sd (none where sd or k is not
    finite: ν_eff < 1 has no finite k)."""
    sd_ = float(sd) if sd is not None and np.isfinite(sd) else None
    half = k * sd_ if sd_ is not None and np.isfinite(k) else None
    e = {
        "mean": float(mean),
        "sd": sd_,
        "hdi_low": float(mean - half) if half is not None else None,
        "hdi_high": float(mean + half) if half is not None else None,
        "unit": unit,
    }
    e.update(extra)
    return e


def posterior_entry(summary_row: Mapping[str, Any], unit: str = "") -> dict:
    """A parameter entry from a posterior summary row (mean, sd, HDI, R-hat, bulk ESS)."""
    keys = ("mean", "sd", "hdi_low", "hdi_high")
    e = {k: summary_row[k] for k in keys}
    e["unit"] = unit
    e["r_hat"] = summary_row["r_hat"]
    e["ess_bulk"] = summary_row["ess_bulk"]
    return e


def _clean(obj: Any) -> Any:
    """NumPy → JSON types; NaN/inf → None (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        f = float(obj)
        return f if math.isfinite(f) else None
    return obj


def base_result(
    *,
    method: str,
    serial: str,
    input_path: str | Path | None,
    input_kind: str,
    g_local_mgal: float,
    meta: dict[str, str],
    hdi_prob: float,
    ccd_center_pix: float,
) -> dict:
    """The header part common to every method; ``input_path`` None: data that came from no
    file (``record`` ``"<memory>"``, no SHA-256)."""
    p = None if input_path is None else Path(input_path)
    return {
        "format": FORMAT,
        "serial": str(serial),
        "record": "<memory>" if p is None else str(input_path),
        "record_sha256": sha256_file(p) if p is not None and p.is_file() else None,
        "input_kind": input_kind,
        "method": method,
        "software": {"name": "chekan", "version": chekan.__version__},
        "created": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "g_local_mgal": float(g_local_mgal),
        "ccd_center_pix": float(ccd_center_pix),
        "hdi_prob": float(hdi_prob),
        "metadata": {k: meta[k] for k in META_KEYS if k in meta},
    }


def classical_result(cres, *, header: dict, b_prior=None, ccd_range_pix=None) -> dict:
    """Fill a result dict from a :class:`chekan.classical.fit.ClassicalResult`."""
    z = z_for(header["hdi_prob"])  # the classical method's intervals are normal
    m0 = header["ccd_center_pix"]
    t = cres.table
    out = dict(header)
    params: dict[str, dict] = {}
    for s in range(2):
        params[f"b{s + 1}"] = interval_entry(cres.b_mean[s], cres.b_mean_sd[s], z, UNITS["b1"])
    fixed: dict[str, float] = {}
    if cres.a_sd is None:
        fixed["a"] = cres.a
    else:
        params["a"] = interval_entry(cres.a, cres.a_sd, z, UNITS["a"])
    b0 = cres.b0(m0)
    if b0 is not None:
        for s in range(2):
            sd0 = cres.b_mean_sd[s]  # the shift 2a(m0 − m_h) is known to far better than b
            params[f"b{s + 1}_0"] = interval_entry(np.nanmean(b0[:, s]), sd0, z, UNITS["b1_0"])
    if cres.eps_arcmin is not None:
        for s in range(2):
            params[f"eps{s + 1}_arcmin"] = interval_entry(
                cres.eps_arcmin[s], cres.eps_sd_arcmin[s], z, "arcmin", source="eq. (17)"
            )
    out["parameters"] = params
    if fixed:
        out["fixed"] = fixed
    if t.m_level_pix is not None:
        mh = np.nanmean(t.m_level_pix, axis=0)
        out["level_reading_pix"] = {"m1": float(mh[0]), "m2": float(mh[1])}
    axes = t.axes
    out["rounds"] = [
        {
            "round": int(r),
            "axis": axes[i],
            "b1": {"mean": cres.b[i, 0], "sd": cres.b_sd[i, 0]},
            "b2": {"mean": cres.b[i, 1], "sd": cres.b_sd[i, 1]},
            **(
                {"b1_0": b0[i, 0], "b2_0": b0[i, 1], "level_reading_pix": list(t.m_level_pix[i])}
                if b0 is not None
                else {}
            ),
            **({"b_printed": list(t.b_printed[i])} if t.b_printed is not None else {}),
            "rms_mgal": {"s1": cres.rms_mgal[i, 0], "s2": cres.rms_mgal[i, 1]},
        }
        for i, r in enumerate(t.rounds)
    ]
    out["mean_b_mgal_per_pix"] = cres.mean_all
    cols = cres.column_names
    R = len(t.rounds)
    out["residuals_mgal"] = {
        "angle_deg": list(t.angle_deg),
        "angle_label": list(t.angle_label),
        "da_ref_mgal": list(np.nanmean(t.da_ref_mgal, axis=0)),
        "columns": cols,
        "dg_mgal": {c: list(cres.dg_mgal[i // 2, i % 2]) for i, c in enumerate(cols)},
        "delta_g_mgal": {c: list(cres.delta_g_mgal[i // 2, i % 2]) for i, c in enumerate(cols)},
        "mean_delta_g_mgal": list(cres.mean_delta_g_mgal),
        "rms_mgal": {c: float(cres.rms_mgal[i // 2, i % 2]) for i, c in enumerate(cols)},
        "da_ref_by_round_mgal": {f"r{r}": list(t.da_ref_mgal[i]) for i, r in enumerate(t.rounds)},
    }
    out["reduced_error_percent"] = cres.reduced_error_percent
    if R >= 2:
        out["discrepancy_between_rounds_percent"] = cres.discrepancy_percent
    inst = cres.instability_percent(b_prior) if b_prior is not None else [None, None]
    if any(v is not None for v in inst):
        out["instability_percent"] = {"b1": inst[0], "b2": inst[1]}
        out["b_prior"] = {"b1": b_prior[0], "b2": b_prior[1]}
    if ccd_range_pix is not None:
        rm = cres.range_margin_gal(ccd_range_pix)
        if rm is not None:
            out["range_margin_gal"] = rm
            out["ccd_range_pix"] = list(ccd_range_pix)
    out["diagnostics"] = {
        "converged": True,
        "sigma_mgal": cres.sigma_mgal,
        "notes": list(cres.notes),
    }
    if cres.problems:
        out["diagnostics"]["problems"] = list(cres.problems)
    out["classical_axis"] = cres.axis
    if cres.by_axis:
        out["classical_by_axis"] = {
            axis: _axis_entry(fit, cres, header, b_prior, ccd_range_pix)
            for axis, fit in cres.by_axis.items()
        }
    return out


def classical_written(
    ready: ReadyInput,
    fit: ClassicalFit,
    opts: CalibrationOptions,
    *,
    input_path: str | Path | None = None,
) -> dict:
    """The ``chekan-result/1`` dict of the classical fit of an input made ready: the header
    (:func:`base_result`), the classical items (:func:`classical_result`), and what the input
    adds (the unsettled hold means, the program's coverage, the record's gaps, the tilt
    program, the angle calibration, the sensor's temperature)."""
    data = ready.data
    record = data if isinstance(data, Record) else None
    if isinstance(data, Record):
        g, m0 = data.g_local_mgal, data.ccd_center_pix
        b_prior, ccd_range = data.b_prior, data.ccd_range_pix
    else:
        g = data.g_local_or_fitted()
        m0 = float(data.meta.get("ccd_center_pix", 1024.0))
        b_prior, ccd_range = None, None
    header = base_result(
        method=opts.method,
        serial=data.serial,
        input_path=input_path,
        input_kind=ready.kind,
        g_local_mgal=g,
        meta=data.meta,
        hdi_prob=opts.hdi_prob,
        ccd_center_pix=m0,
    )
    if record is not None and "started" in data.meta:
        header["date"] = data.meta["started"][:10]
    elif "date" in data.meta:
        header["date"] = data.meta["date"]
    cres, holds = fit.result, ready.holds
    result = classical_result(cres, header=header, b_prior=b_prior, ccd_range_pix=ccd_range)
    if fit.unsettled is not None:
        result["unsettled_hold_means"] = fit.unsettled.entry()
    if ready.coverage is not None:
        result["program_coverage"] = ready.coverage
    if holds is not None and holds.gaps:
        result["record_gaps"] = gaps_entry(holds)
    name = data.meta.get("program") or None
    if holds is not None:
        result["tilt_program"] = tilt_program_entry(holds=holds, name=name)
    else:
        result["tilt_program"] = tilt_program_entry(table=cres.table, name=name)
    if record is not None and record.angle_calibration is not None:
        result["angle_calibration"] = record.angle_calibration.entry()
    if record is not None and record.temp_c is not None and np.isfinite(record.temp_c).any():
        temp = record.temp_c[np.isfinite(record.temp_c)]
        result["sensor_temperature_c"] = {
            "mean": round(float(temp.mean()), 3),
            "min": round(float(temp.min()), 3),
            "max": round(float(temp.max()), 3),
        }
    return result


def tilt_program_entry(holds=None, table=None, name: str | None = None) -> dict:
    """The tilt program as run, for the certificate: each round's number, axis and angle
    magnitudes, and (from a record's holds) the median dwell and the settling time used.
    From a record's ``holds`` (every round, both axes) or else a protocol's increment
    ``table``."""
    out: dict[str, Any] = {"name": name} if name else {}
    if holds is not None:
        labels = holds.angle_labels
        rounds = []
        for r in holds.rounds:
            idx = sorted({int(holds.angle_index[i]) for i in r.tilt_holds})
            rounds.append({"round": r.number, "axis": r.axis, "angles": [labels[i] for i in idx]})
        span = np.asarray(holds.t_end_s, dtype=float) - np.asarray(holds.t_start_s, dtype=float)
        count = np.asarray(holds.stop) - np.asarray(holds.start)  # samples: span + one interval
        dwell = span * count / np.maximum(count - 1, 1)
        out.update(
            source="record",
            rounds=rounds,
            angles=labels,
            dwell_s=round(float(np.median(dwell)), 1),
            settle_s=float(holds.settle_s),
        )
    elif table is not None:
        out.update(
            source="protocol",
            rounds=[
                {"round": int(r), "axis": a, "angles": list(table.angle_label)}
                for r, a in zip(table.rounds, table.axes, strict=True)
            ],
            angles=list(table.angle_label),
        )
    return out


#: The keys of a classical result that each axis's fit repeats in ``classical_by_axis``.
AXIS_KEYS = (
    "parameters",
    "fixed",
    "level_reading_pix",
    "rounds",
    "mean_b_mgal_per_pix",
    "residuals_mgal",
    "reduced_error_percent",
    "discrepancy_between_rounds_percent",
)


def _axis_entry(fit, cert, header: dict, b_prior, ccd_range_pix) -> dict:
    """The classical result of one axis's rounds, and whether the certificate uses it."""
    import dataclasses

    full = classical_result(
        dataclasses.replace(fit, by_axis={}),
        header=header,
        b_prior=b_prior,
        ccd_range_pix=ccd_range_pix,
    )
    entry = {k: full[k] for k in AXIS_KEYS if k in full}
    entry["sigma_mgal"] = fit.sigma_mgal
    entry["used_by_certificate"] = fit is cert
    return entry


#: The classical items of a joint result that a settled refit replaces (:func:`with_settled`).
ITEM_KEYS = (
    "rounds",
    "mean_b_mgal_per_pix",
    "residuals_mgal",
    "reduced_error_percent",
    "discrepancy_between_rounds_percent",
    "range_margin_gal",
    "classical_by_axis",
)


def certified_instability(result: Mapping[str, Any]) -> dict:
    """``result`` (not changed) with the instability of its own b₁, b₂ against the prior,
    δb = (b − b_prior)/b_prior · 100 %: the certificate judges the values it states (with
    their U), not the classical ones beside them."""
    out = dict(result)
    prior = result.get("b_prior") or {}
    inst = {}
    for name in ("b1", "b2"):
        b, p = (result["parameters"].get(name) or {}).get("mean"), prior.get(name)
        if isinstance(b, int | float) and isinstance(p, int | float) and p:
            inst[name] = float((b - p) / p * 100.0)
    if inst:
        out["instability_percent"] = inst
    return out


def with_settled(result: Mapping[str, Any], found: Settling) -> dict:
    """The joint ``result`` (not changed) with what :func:`chekan.classical.settling.settle`
    found: the certified instability (:func:`certified_instability`); unconverged, the
    classical fit's ``unsettled_hold_means`` where it had none; settled hold means, no such
    flag; a settled refit, its items (:data:`ITEM_KEYS`) and classical b in place of
    Calibr.exe's, which go under ``hold_transient.calibr_exe`` with the transient's size."""
    out = certified_instability(result)
    if not found.converged:
        if found.unsettled is not None and "unsettled_hold_means" not in out:
            out["unsettled_hold_means"] = found.unsettled.entry()
        return out
    if found.transient_max_pix is None:
        out.pop("unsettled_hold_means", None)  # the classical fit's flag: the model finds
        return out  # the hold means settled
    if found.refit is None:
        return out  # Calibr.exe's items stand, with their flag
    items = classical_result(
        found.refit,
        header=dict(result),
        b_prior=found.b_prior,
        ccd_range_pix=found.ccd_range_pix,
    )
    out.pop("unsettled_hold_means", None)  # the items are settled now
    kept = ("reduced_error_percent", "discrepancy_between_rounds_percent", "mean_b_mgal_per_pix")
    before = {k: result[k] for k in kept if k in result}
    before.update({k: dict(v) for k, v in (result.get("classical") or {}).items()})
    out["hold_transient"] = {
        "max_pix": found.transient_max_pix,
        "tau_s": found.tau_s,
        "settle_s": found.settle_s,
        "calibr_exe": before,
    }
    for key in ITEM_KEYS:
        out.pop(key, None)
        if key in items:
            out[key] = items[key]
    out["classical"] = {k: items["parameters"][k] for k in ("b1", "b2")}
    return out


def write_result(path: str | Path, result: dict) -> Path:
    """Write ``result`` as JSON, atomically (a crash leaves the old file or none)."""
    from chekan.files.durable import atomic_output

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(_clean(result), indent=2, ensure_ascii=False) + "\n"
    with atomic_output(path) as f:
        f.write(text)
    return path


def read_result(path: str | Path) -> dict:
    """Read and check a result file: the spec's fixed keys must be present and sane."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FormatError(path, None, "no such result file") from None
    except json.JSONDecodeError as e:
        raise FormatError(path, e.lineno, f"not valid JSON: {e.msg}") from None
    check_result(data, path)
    return data


def check_result(data: Any, path: str | Path = "<result>") -> None:
    if not isinstance(data, dict):
        raise FormatError(path, None, "a result must be a JSON object")
    if data.get("format") != FORMAT:
        raise FormatError(path, None, f"format must be {FORMAT!r}, not {data.get('format')!r}")
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise FormatError(path, None, f"missing key(s): {', '.join(missing)}")
    if data["method"] not in METHODS:
        raise FormatError(
            path, None, f"unknown method {data['method']!r}; expected one of {', '.join(METHODS)}"
        )
    params = data["parameters"]
    if not isinstance(params, dict):
        raise FormatError(path, None, "'parameters' must be an object")
    for name in ("b1", "b2"):
        if name not in params:
            raise FormatError(path, None, f"parameters.{name} is missing")
    for name, e in params.items():
        if not isinstance(e, dict) or "mean" not in e:
            raise FormatError(path, None, f"parameters.{name} has no 'mean'")
    for name in ("b1", "b2"):
        mean = params[name]["mean"]
        ok = isinstance(mean, int | float) and not isinstance(mean, bool)
        if not ok or not math.isfinite(mean) or mean <= 0.0:
            raise FormatError(
                path, None, f"parameters.{name}.mean is {mean!r}: not a positive finite number"
            )


def settled_items(
    result: Mapping[str, Any],
    holds: Any,
    record: Any,
    *,
    classical: Any = None,
    a_fixed: float | None = None,
) -> dict:
    """The joint ``result`` (not changed) with its classical items from settled hold means.

    Where the lag leaves more than :data:`chekan.classical.settling.UNSETTLED_PIX` in some
    hold mean (:func:`chekan.classical.settling.unsettled_transient_pix`), the classical
    method (eqs. 21–25, as Calibr.exe) runs again on the hold means less that transient; its
    items (:data:`ITEM_KEYS`) and the classical b replace those computed from the raw hold
    means, which are kept under
    ``hold_transient.calibr_exe`` with the transient's size. Elsewhere, and where the fit
    did not converge, the items stay Calibr.exe's; in the latter case with the
    ``classical`` fit's :func:`unsettled_hold_means` where it applies. Either way the
    instability (item д), the verdict) is that of the result's own b₁, b₂, the certified
    values (:func:`certified_instability`): :func:`settle` of the result's values, written by
    :func:`with_settled`."""
    from chekan.classical.settling import JointValues, settle

    if "unsettled_hold_means" in result:  # the flag is there already
        classical = None
    found = settle(
        JointValues.of_result(result), holds, record, classical=classical, a_fixed=a_fixed
    )
    return with_settled(result, found)
