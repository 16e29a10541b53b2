"""One calibration end to end: record or protocol → estimator → ``chekan-result/1`` dict.

:func:`calibrate` takes an in-memory :class:`~chekan.records.Record` or
:class:`~chekan.records.protocol.Protocol`; :func:`calibrate_file` reads a file and calls it. Used
by ``chekan calibrate``, re-analysis, validation, the live page and the demo, so they agree.
"""

from __future__ import annotations

from pathlib import Path

from chekan.classical.fit import ClassicalFit, classical_fit
from chekan.errors import ChekanError
from chekan.options import METHODS, CalibrationOptions
from chekan.records import Record
from chekan.records.framing import count_rows
from chekan.records.holds import HoldTable
from chekan.records.inputs import ReadyInput, input_kind, read_input, ready_input
from chekan.records.protocol import Protocol
from chekan.results.document import classical_written

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

    The way of every input: :func:`~chekan.records.inputs.ready_input` (angle calibration,
    holds), :func:`~chekan.classical.fit.classical_fit`, written by
    :func:`~chekan.results.document.classical_written`; for ``map`` and ``bayes`` then the
    joint fit (:func:`chekan.fit.estimate`) written over it
    (:func:`chekan.results.joint.joint_result`).

    ``input_path``: the file the data was read from, unchanged (the result names it and its
    SHA-256); ``None``: the data is the input itself (``record`` is :data:`IN_MEMORY`, no
    hash), as for a simulated session or a record still being written.
    """
    opts = _checked(options)
    ready, fit, result = classical_of(data, opts, input_path)
    if opts.method == "classical":
        return result
    # once the input has been read (a bad file fails at once, not after the loads), before
    # the heavy imports: a new process starts loading, in the background, the compiled
    # functions that the last calibration of this method and program ran
    from chekan.runtime.process import executable_store

    store = executable_store()
    label = preload_label(result, opts)
    store.preload(label)
    out = joint_stage(ready.data, ready.kind, fit.result, result, opts, holds=ready.holds)
    store.remember(label)
    return out


def joint_stage(
    data: Record | Protocol,
    kind: str,
    cres,
    result: dict,
    opts: CalibrationOptions,
    *,
    holds: HoldTable | None = None,
) -> dict:
    """The ``map`` or ``bayes`` result of ``data``: the joint fit
    (:func:`chekan.fit.estimate`; ``holds``: a record's, where found already), written over
    its classical ``result`` (not changed) by :func:`chekan.results.joint.joint_result`."""
    from chekan.fit import estimate
    from chekan.results.joint import joint_result  # heavy imports only when needed

    source = str(result.get("record", "record"))  # the input's name, for messages
    fitted = estimate(data, kind=kind, classical=cres, source=source, options=opts, holds=holds)
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


def input_ready(
    data: Record | Protocol, opts: CalibrationOptions, input_path: str | Path | None = None
) -> ReadyInput:
    """:func:`~chekan.records.inputs.ready_input` of ``data`` with the options' angle calibration
    and settling time."""
    return ready_input(
        data,
        angle_calibration=opts.angle_calibration,
        settle_s=opts.settle_s,
        input_path=input_path,
    )


def classical_stage(path: str | Path, opts: CalibrationOptions):
    """Read ``path`` and run the classical method: ``(data, kind, classical fit, result)``,
    ``data`` as the joint methods take it (:func:`joint_stage`)."""
    ready, fit, result = classical_of(read_input(path), _checked(opts), path)
    return ready.data, ready.kind, fit.result, result


def classical_of(
    data: Record | Protocol, opts: CalibrationOptions, input_path: str | Path | None = None
) -> tuple[ReadyInput, ClassicalFit, dict]:
    """The classical method on ``data``: the input made ready (:func:`input_ready`), its
    classical fit (the unsettled hold means looked for by ``--method classical`` alone: a
    joint result settles its items itself) and the result written of it."""
    ready = input_ready(data, opts, input_path)
    fit = classical_fit(ready, a_fixed=opts.a_fixed, unsettled=opts.method == "classical")
    return ready, fit, classical_written(ready, fit, opts, input_path=input_path)
