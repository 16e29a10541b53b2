"""One calibration end to end: input file → estimator → ``chekan-result/1`` dict.

Used by ``chekan calibrate``, batch re-analysis and the demo, so they agree.
"""

from __future__ import annotations

from pathlib import Path

from chekan.errors import ChekanError
from chekan.inputs import read_input
from chekan.options import METHODS, CalibrationOptions
from chekan.result import base_result, classical_result


def calibrate_file(path: str | Path, options: CalibrationOptions | None = None) -> dict:
    """Calibrate a record or a legacy protocol with the chosen method; return the result dict."""
    opts = options or CalibrationOptions()
    data, kind, cres, result = classical_stage(path, opts)
    if opts.method == "classical":
        return result
    # once the input has been read (a bad file fails at once, not after the loads), before
    # the heavy imports: a new process starts loading, in the background, the compiled
    # functions that the last calibration of this method ran
    from chekan.jaxconfig import executable_store

    store = executable_store()
    store.preload(f"calibrate-{opts.method}")
    from chekan.joint import estimate  # heavy imports only when needed

    out = estimate(data, kind=kind, classical=cres, base=result, options=opts)
    store.remember(f"calibrate-{opts.method}")
    return out


def classical_stage(path: str | Path, opts: CalibrationOptions):
    """Read the input and run the classical method: ``(data, kind, classical fit, result)``.

    Every method starts here (the classical fit seeds the MAP and is reported beside it).
    """
    if opts.method not in METHODS:
        raise ChekanError(f"unknown method {opts.method!r}; choose one of {', '.join(METHODS)}")
    data = read_input(path)
    kind = "protocol" if hasattr(data, "dg_mgal") else "record"
    if kind == "record":
        g = data.g_local_mgal
        m0 = data.ccd_center_pix
        b_prior = data.b_prior
        ccd_range = data.ccd_range_pix
    else:
        g = data.g_local_or_fitted()
        m0 = float(data.meta.get("ccd_center_pix", 1024.0))
        b_prior = None
        ccd_range = None
    header = base_result(
        method=opts.method,
        serial=data.serial,
        input_path=path,
        input_kind=kind,
        g_local_mgal=g,
        meta=data.meta,
        hdi_prob=opts.hdi_prob,
        ccd_center_pix=m0,
    )
    if kind == "record" and "started" in data.meta:
        header["date"] = data.meta["started"][:10]
    elif "date" in data.meta:
        header["date"] = data.meta["date"]
    from chekan import classical

    if kind == "record":
        cres, _holds = classical.calibrate_record(
            data, settle_s=opts.settle_s, a_fixed=opts.a_fixed
        )
    else:
        cres = classical.calibrate_protocol(data, a_fixed=opts.a_fixed)
    result = classical_result(cres, header=header, b_prior=b_prior, ccd_range_pix=ccd_range)
    return data, kind, cres, result
