"""The certificate's input check: the optional parts of a ``chekan-result/1`` dict that
the certificate reads, each refused with a :class:`FormatError` naming it."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from chekan.errors import FormatError
from chekan.report.numbers import is_num


def _fail(src: str, problem: str) -> FormatError:
    return FormatError(src, None, problem)


def _need_list(obj: Any, where: str, src: str, n: int | None = None) -> list:
    if not isinstance(obj, list):
        raise _fail(src, f"{where} must be a list")
    if n is not None and len(obj) != n:
        raise _fail(src, f"{where} has {len(obj)} values, expected {n} (one per angle)")
    return obj


def _need_dict(obj: Any, where: str, src: str) -> dict:
    if not isinstance(obj, dict):
        raise _fail(src, f"{where} must be an object")
    return obj


def _check_classical_part(part: Mapping[str, Any], at: str, src: str) -> None:
    """The parameters, residual tables and rounds of a result (or of one axis's fit in
    ``classical_by_axis``, ``at`` its prefix)."""
    for name, e in _need_dict(part.get("parameters", {}), f"{at}parameters", src).items():
        if not isinstance(e, dict) or not is_num(e.get("mean")):
            raise _fail(src, f"{at}parameters.{name}.mean is not a number")
    rs = part.get("residuals_mgal")
    if rs is not None:
        _need_dict(rs, f"{at}residuals_mgal", src)
        for k in ("angle_label", "columns", "da_ref_mgal", "dg_mgal", "delta_g_mgal"):
            if k not in rs:
                raise _fail(src, f"{at}residuals_mgal.{k} is missing")
        n = len(_need_list(rs["angle_label"], f"{at}residuals_mgal.angle_label", src))
        _need_list(rs["da_ref_mgal"], f"{at}residuals_mgal.da_ref_mgal", src, n)
        if "mean_delta_g_mgal" in rs:
            _need_list(rs["mean_delta_g_mgal"], f"{at}residuals_mgal.mean_delta_g_mgal", src, n)
        for c in _need_list(rs["columns"], f"{at}residuals_mgal.columns", src):
            for k in ("dg_mgal", "delta_g_mgal"):
                d = _need_dict(rs[k], f"{at}residuals_mgal.{k}", src)
                if c not in d:
                    raise _fail(src, f"{at}residuals_mgal.{k} has no column {c!r}")
                _need_list(d[c], f"{at}residuals_mgal.{k}.{c}", src, n)
    for i, r in enumerate(_need_list(part.get("rounds", []), f"{at}rounds", src)):
        _need_dict(r, f"{at}rounds[{i}]", src)
        for s in ("b1", "b2"):
            if not isinstance(r.get(s), dict) or "mean" not in r[s]:
                raise _fail(src, f"{at}rounds[{i}].{s}.mean is missing")


def check_certificate_input(result: Mapping[str, Any], src: str) -> None:
    """Check the optional parts the certificate reads; raise :class:`FormatError` naming them."""
    _check_classical_part(result, "", src)
    by_axis = result.get("classical_by_axis")
    if by_axis is not None:
        for axis, entry in _need_dict(by_axis, "classical_by_axis", src).items():
            where = f"classical_by_axis.{axis}"
            if axis not in ("x", "y"):
                raise _fail(src, f"{where}: the axis must be 'x' or 'y'")
            _check_classical_part(_need_dict(entry, where, src), where + ".", src)
    bud = result.get("uncertainty_budget")
    if bud is not None:
        for s, comp in _need_dict(bud, "uncertainty_budget", src).items():
            for k, v in _need_dict(comp, f"uncertainty_budget.{s}", src).items():
                if v is not None and not is_num(v):
                    raise _fail(src, f"uncertainty_budget.{s}.{k} is not a number")
    dc = result.get("drift_curve")
    if dc is not None:
        _need_dict(dc, "drift_curve", src)
        if "t_h" not in dc:
            raise _fail(src, "drift_curve.t_h is missing")
        n = len(_need_list(dc["t_h"], "drift_curve.t_h", src))
        for k, v in dc.items():
            if len(_need_list(v, f"drift_curve.{k}", src)) != n:
                raise _fail(src, f"drift_curve.{k} has {len(v)} values, t_h has {n}")
    pp = result.get("posterior_predictive_mgal")
    if pp is not None:
        _need_dict(pp, "posterior_predictive_mgal", src)
        for k in ("delta_g_low", "delta_g_high"):
            _need_dict(pp.get(k), f"posterior_predictive_mgal.{k}", src)
    for key in (
        "range_margin_gal",
        "instability_percent",
        "diagnostics",
        "metadata",
        "angle_sensor",
    ):
        if result.get(key) is not None:
            _need_dict(result[key], key, src)
