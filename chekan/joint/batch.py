"""MAP of many records at once: pad to one structure, solve all lanes with one vmapped LM.

Batch re-analysis (``chekan reanalyze --method map``) hands over chunks of records. Each
is laid out by :func:`chekan.joint.binning.prepare`, padded to the chunk's common
(holds, bins, slew samples) by :meth:`chekan.joint.layout.RecordModel.pad` (exact:
padding carries zero weight), and every EM pass is one vmapped LM solve over the chunk
(:func:`chekan.joint.map.fit_map_em_many`). The padded shape is rounded up so that
similar chunks share one compiled solver.

A record that fails in preparation fails alone; if the batched solve itself fails, the
chunk falls back to one record at a time, so a batch never loses a record it could do.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence

from chekan.jaxconfig import single_threaded_blas
from chekan.joint.binning import prepare
from chekan.joint.estimate import map_result
from chekan.joint.layout import padded_shape
from chekan.joint.map import fit_map_em, fit_map_em_many
from chekan.joint.start import initial_values, tau_from_transients
from chekan.options import CalibrationOptions


def estimate_map_many(
    items: Sequence[tuple], options: CalibrationOptions
) -> list[dict | Exception]:
    """``map`` results for ``items`` = [(record, classical fit, base result)], one per item
    (or the exception that item raised); BLAS on one thread
    (:func:`chekan.jaxconfig.single_threaded_blas`)."""
    with single_threaded_blas():
        return _estimate_map_many(items, options)


def _estimate_map_many(
    items: Sequence[tuple], options: CalibrationOptions
) -> list[dict | Exception]:
    t_start = time.perf_counter()
    out: list[dict | Exception | None] = [None] * len(items)
    ready = []  # (index, model, init, τ hint)
    for i, (record, cres, _base) in enumerate(items):
        try:
            holds, model = prepare(
                record,
                options.settle_s,
                encoder=options.encoder_error,
                angle_spec=options.angle_spec(record.meta, calibration=record.angle_calibration),
                angle_spec_x=options.angle_spec(
                    record.meta, calibration=record.angle_calibration, axis="x"
                ),
            )
            ready.append(
                (
                    i,
                    model,
                    initial_values(cres, record.g_local_mgal),
                    functools.partial(tau_from_transients, record, holds),
                )
            )
        except Exception as e:  # one bad record never spoils the chunk
            out[i] = e
    if ready:
        H, N, M, S = padded_shape([r[1] for r in ready])
        padded = [r[1].pad(H, N, M, S) for r in ready]
        try:
            fits = fit_map_em_many(padded, [r[2] for r in ready], tau_hints_s=[r[3] for r in ready])
        except Exception:  # e.g. out of memory: do them one by one
            fits = None
        for k, (i, model, init, hint) in enumerate(ready):
            base = items[i][2]
            try:
                fit = fit_map_em(model, init, tau_hint_s=hint) if fits is None else fits[k]
                per = (time.perf_counter() - t_start) / len(ready)
                out[i] = map_result(fit, base, options, time.perf_counter() - per)
            except Exception as e:
                out[i] = e
    return out  # type: ignore[return-value]
