"""One calibration end to end: record or protocol → estimator → ``chekan-result/1`` dict.

:func:`calibrate` takes an in-memory :class:`~chekan.records.Record` or
:class:`~chekan.records.protocol.Protocol`; :func:`calibrate_file` reads a file and calls it. Used
by ``chekan calibrate``, re-analysis, validation, the live page and the demo, so they agree.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from chekan.classical.fit import ClassicalResult
from chekan.classical.settling import Unsettled, unsettled_hold_means
from chekan.errors import ChekanError
from chekan.options import METHODS, CalibrationOptions
from chekan.records import Record
from chekan.records.framing import count_rows
from chekan.records.holds import HoldTable, gaps_entry, program_coverage
from chekan.records.inputs import input_kind, read_input
from chekan.records.protocol import Protocol
from chekan.results.document import base_result, classical_result, tilt_program_entry

#: ``result["record"]`` of a calibration of data that came from no file.
IN_MEMORY = "<memory>"


#: The largest record (data rows) the joint methods take. Peak memory and time of
#: ``chekan calibrate --method map`` on the paper's program repeated (2 shared CPU cores,
#: 2026-11-25): 49 491 rows 1.14 GB, 98 982 rows 1.44 GB, 197 964 rows 1.47 GB, 395 928 rows
#: 1.48 GB (2.5–4 min each); beyond, 1 022 814 rows took 3.51 GB and 8.7 min.
MAX_JOINT_ROWS = 400_000


def check_size(path: str | Path, method: str) -> None:
    """Refuse a record beyond :data:`MAX_JOINT_ROWS` for ``map``/``bayes`` before reading it
    (its rows are counted in chunks; nothing is parsed)."""
    if method == "classical" or input_kind(path) != "record":
        return
    n = count_rows(path)
    if n > MAX_JOINT_ROWS:
        mb = Path(path).stat().st_size / 1e6
        rows, limit = (f"{k:_}".replace("_", " ") for k in (n, MAX_JOINT_ROWS))
        raise ChekanError(
            f"{path}: {rows} rows ({mb:.1f} MB): --method {method} takes records of at most "
            f"{limit} rows (about 111 h at 1 Hz); split the record, or use --method classical"
        )


def calibrate_file(path: str | Path, options: CalibrationOptions | None = None) -> dict:
    """Calibrate the record or legacy protocol in ``path``: :func:`calibrate` of what it
    holds, the result naming the file and its SHA-256. A record too large for the joint
    methods is refused before it is read (:func:`check_size`)."""
    opts = _checked(options)
    check_size(path, opts.method)
    return calibrate(read_input(path), opts, input_path=path)


def calibrate(
    data: Record | Protocol,
    options: CalibrationOptions | None = None,
    *,
    input_path: str | Path | None = None,
) -> dict:
    """Calibrate an in-memory record or protocol with the chosen method; the result dict.

    ``input_path``: the file the data was read from, unchanged (the result names it and its
    SHA-256); ``None``: the data is the input itself (``record`` is :data:`IN_MEMORY`, no
    hash), as for a simulated session or a record still being written.
    """
    opts = _checked(options)
    data = with_angle_calibration(data, opts, input_path)
    kind, cres, result = classical_of(data, opts, input_path=input_path)
    if opts.method == "classical":
        return result
    # once the input has been read (a bad file fails at once, not after the loads), before
    # the heavy imports: a new process starts loading, in the background, the compiled
    # functions that the last calibration of this method and program ran
    from chekan.runtime.process import executable_store

    store = executable_store()
    label = preload_label(result, opts)
    store.preload(label)
    out = joint_stage(data, kind, cres, result, opts)
    store.remember(label)
    return out


def joint_stage(
    data: Record | Protocol, kind: str, cres, result: dict, opts: CalibrationOptions
) -> dict:
    """The ``map`` or ``bayes`` result of ``data``: the joint fit
    (:func:`chekan.fit.record`), written over its classical ``result`` (not changed) by
    :func:`chekan.results.joint.joint_result`."""
    from chekan.fit import estimate
    from chekan.results.joint import joint_result  # heavy imports only when needed

    source = str(result.get("record", "record"))  # the input's name, for messages
    fitted = estimate(data, kind=kind, classical=cres, source=source, options=opts)
    return joint_result(result, fitted, opts)


def preload_label(result: dict, opts: CalibrationOptions) -> str:
    """The label under which the executable store keeps and preloads the executables of
    this calibration (:meth:`~chekan.runtime.store.ExecutableStore.preload`): the method and a hash
    of what shapes the joint model — the tilt program as the classical result states it
    (axes, angles, rounds, dwell; not its name) and the options that add or drop model
    terms — so that a process preloads what the last calibration of the *same* program ran,
    not another program's executables (a guess: a wrong one only wastes background time)."""
    import hashlib
    import json

    program = {k: v for k, v in (result.get("tilt_program") or {}).items() if k != "name"}
    shape = {
        "program": program,
        "input": result.get("input_kind"),
        "options": [
            opts.encoder_error,
            opts.angle_errors,
            opts.angle_calibration is not None,
            opts.settle_s,
            opts.quick,
            opts.map_solver,
        ],
    }
    text = json.dumps(shape, sort_keys=True, default=str)
    return f"calibrate-{opts.method}-{hashlib.sha256(text.encode()).hexdigest()[:12]}"


def _checked(options: CalibrationOptions | None) -> CalibrationOptions:
    opts = options or CalibrationOptions()
    if opts.method not in METHODS:
        raise ChekanError(f"unknown method {opts.method!r}; choose one of {', '.join(METHODS)}")
    return opts


def kind_of(data: Record | Protocol) -> str:
    """``"record"`` or ``"protocol"``; anything else is an error."""
    if isinstance(data, Record):
        return "record"
    if isinstance(data, Protocol):
        return "protocol"
    raise ChekanError(f"cannot calibrate a {type(data).__name__}: give a Record or a Protocol")


def classical_stage(path: str | Path, opts: CalibrationOptions):
    """Read ``path`` and run the classical method: ``(data, kind, classical fit, result)``."""
    opts = _checked(opts)
    data = with_angle_calibration(read_input(path), opts, path)
    return (data, *classical_of(data, opts, input_path=path))


def with_angle_calibration(
    data: Record | Protocol, opts: CalibrationOptions, input_path: str | Path | None = None
) -> Record | Protocol:
    """``data`` with the platform's angle calibration applied (:mod:`chekan.records.anglecal`: the
    option's table, else the one the record's header names), or unchanged without one."""
    from chekan.records.anglecal import calibration_for, corrected

    if kind_of(data) == "protocol":
        if opts.angle_calibration is not None:
            raise ChekanError(
                f"{input_path or 'protocol'}: an angle calibration corrects a record's measured"
                " angles; a legacy protocol holds only its commanded angles"
            )
        return data
    assert isinstance(data, Record)
    if data.angle_calibration is not None:
        return data  # already applied
    cal = calibration_for(data, opts.angle_calibration, input_path)
    return data if cal is None else corrected(data, cal)


@dataclass(frozen=True)
class ClassicalFit:
    """The classical method on one input (:func:`classical_fit`): the input's kind, the fit
    (its problems include the program's coverage and, for ``--method classical``, the
    unsettled hold means), and of a record its holds, what of the program it lacks
    (:func:`chekan.records.holds.program_coverage`, or None) and its unsettled hold means
    (or None)."""

    kind: str
    result: ClassicalResult
    holds: HoldTable | None = None
    coverage: dict | None = None
    unsettled: Unsettled | None = None


def classical_fit(data: Record | Protocol, opts: CalibrationOptions) -> ClassicalFit:
    """The classical method on ``data`` (eqs. 16–25, :mod:`chekan.classical.fit`). Every method
    starts here (the classical fit seeds the MAP and is reported beside it)."""
    from chekan.classical import fit as classical

    kind = kind_of(data)
    if not isinstance(data, Record):
        return ClassicalFit(kind, classical.calibrate_protocol(data, a_fixed=opts.a_fixed))
    cres, holds = classical.calibrate_record(data, settle_s=opts.settle_s, a_fixed=opts.a_fixed)
    coverage = program_coverage(holds, data.meta)
    if coverage is not None:
        cres = _flagged(cres, coverage["problems"])
    unsettled = None
    if (
        opts.method == "classical"
    ):  # a joint result settles its items (chekan.classical.settling.settle)
        unsettled = unsettled_hold_means(holds, data, cres, a_fixed=opts.a_fixed)
    if unsettled is not None:
        cres = _flagged(cres, [unsettled.problem])
    return ClassicalFit(kind, cres, holds, coverage, unsettled)


def _flagged(cres, problems: list[str]):
    """``cres`` with ``problems`` added; its per-axis fits name the certificate's own by
    identity, so the copy stands for it there too."""
    flagged = dataclasses.replace(cres, problems=[*cres.problems, *problems])
    flagged.by_axis = {a: flagged if f is cres else f for a, f in cres.by_axis.items()}
    return flagged


def classical_written(
    data: Record | Protocol,
    fit: ClassicalFit,
    opts: CalibrationOptions,
    *,
    input_path: str | Path | None = None,
) -> dict:
    """The ``chekan-result/1`` dict of a classical fit of ``data``: the header
    (:func:`chekan.results.document.base_result`), the classical items
    (:func:`chekan.results.document.classical_result`), and what the input adds (the unsettled hold
    means, the program's coverage, the record's gaps, the tilt program, the angle
    calibration, the sensor's temperature)."""
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
        input_kind=fit.kind,
        g_local_mgal=g,
        meta=data.meta,
        hdi_prob=opts.hdi_prob,
        ccd_center_pix=m0,
    )
    if fit.kind == "record" and "started" in data.meta:
        header["date"] = data.meta["started"][:10]
    elif "date" in data.meta:
        header["date"] = data.meta["date"]
    cres, holds = fit.result, fit.holds
    result = classical_result(cres, header=header, b_prior=b_prior, ccd_range_pix=ccd_range)
    if fit.unsettled is not None:
        result["unsettled_hold_means"] = fit.unsettled.entry()
    if fit.coverage is not None:
        result["program_coverage"] = fit.coverage
    if holds is not None and holds.gaps:
        result["record_gaps"] = gaps_entry(holds)
    name = data.meta.get("program") or None
    if holds is not None:
        result["tilt_program"] = tilt_program_entry(holds=holds, name=name)
    else:
        result["tilt_program"] = tilt_program_entry(table=cres.table, name=name)
    if isinstance(data, Record) and data.angle_calibration is not None:
        result["angle_calibration"] = data.angle_calibration.entry()
    if isinstance(data, Record) and data.temp_c is not None and np.isfinite(data.temp_c).any():
        temp = data.temp_c[np.isfinite(data.temp_c)]
        result["sensor_temperature_c"] = {
            "mean": round(float(temp.mean()), 3),
            "min": round(float(temp.min()), 3),
            "max": round(float(temp.max()), 3),
        }
    return result


def classical_of(
    data: Record | Protocol, opts: CalibrationOptions, *, input_path: str | Path | None = None
) -> tuple[str, ClassicalResult, dict]:
    """The classical method on ``data``: ``(kind, classical fit, result)``
    (:func:`classical_fit`, written by :func:`classical_written`)."""
    fit = classical_fit(data, opts)
    return fit.kind, fit.result, classical_written(data, fit, opts, input_path=input_path)
