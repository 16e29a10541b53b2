"""MAP of many records at once: pad to one shape, solve all lanes with one vmapped LM.

Batch re-analysis (``chekan reanalyze --method map``) hands over chunks of records. Each
is laid out by :func:`chekan.calmodel.prepare_record`, padded to the chunk's common
(holds, bins, slew samples) by :func:`chekan.calmodel.pad_model` (exact: padding carries
zero weight), and every EM pass of :func:`chekan.bayes.fit_map_em` becomes one
:func:`inference.map.fit_map_batch` call over the chunk. Hyperparameter updates and the
derived quantities stay per record. The padded shape is rounded up so that similar
chunks share one compiled solver.

A record that fails in preparation fails alone; if the batched solve itself fails, the
chunk falls back to one record at a time, so a batch never loses a record it could do.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from chekan import bayes
from chekan import calmodel as cm
from inference.map import fit_map_batch

# vmapped lanes per solve: the XLA CPU runtime (jax 0.10) deadlocks on this model's
# vmapped LM at 4 lanes and more (measured; see inference.map.fit_map_batch); on CPU a
# vmapped solve costs about the sum of its lanes anyway, so pairs lose nothing
MAX_LANES = 2


def _stack(trees: list[dict]) -> dict:
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *trees)


def fit_map_em_batch(prob: cm.CalibrationProblem, models: list, inits: list[dict]):
    """:func:`chekan.bayes.fit_map_em` for many padded models of one shape at once.

    Returns per lane ``(MapResult, hyper dict, history)``.
    """
    B = len(models)
    space = prob.map_space
    hs = [cm.hyper_dict() for _ in range(B)]
    z0 = np.stack([space.to_z(i) for i in inits])
    histories: list[list[dict]] = [[] for _ in range(B)]
    batch = None
    for it in range(bayes.MAP_PASSES):
        datas = [{**m.data, "hyper": h} for m, h in zip(models, hs, strict=True)]
        batch = fit_map_batch(prob.lsq, _stack(datas), z0, max_lanes=MAX_LANES)
        z0 = batch.z
        for i in range(B):
            updates = 0
            if it < bayes.MAP_PASSES - 1:  # per lane: its own model, the shared solvers
                hs[i], updates = bayes.between_passes(
                    bayes.problem_for(models[i]), batch.z[i], hs[i]
                )
            histories[i].append(
                bayes._pass_entry(
                    it, batch.converged[i], batch.num_steps[i], batch.cost[i], False, updates
                )
            )
    return [(batch.item(i), hs[i], histories[i]) for i in range(B)]


def estimate_map_many(items: Sequence[tuple], options) -> list[dict | Exception]:
    """``map`` results for ``items`` = [(record, classical fit, base result)], one per item
    (or the exception that item raised)."""
    t_start = time.perf_counter()
    out: list[dict | Exception | None] = [None] * len(items)
    ready = []  # (index, holds, model, init)
    for i, (record, cres, _base) in enumerate(items):
        try:
            holds, model = bayes.prepare(record, options)
            ready.append((i, holds, model, bayes.initial_values(cres, record.g_local_mgal)))
        except Exception as e:  # one bad record never spoils the chunk
            out[i] = e
    if ready:
        H, N, M = cm.padded_shape([r[2] for r in ready])
        padded = [cm.pad_model(r[2], H, N, M) for r in ready]
        prob = bayes.problem_for(padded[0])
        try:
            fits = fit_map_em_batch(prob, padded, [r[3] for r in ready])
        except Exception:  # e.g. out of memory: do them one by one
            fits = None
        for k, (i, holds, model, init) in enumerate(ready):
            record, _cres, base = items[i]
            try:
                if fits is None:
                    p_i = bayes.problem_for(model)
                    res, h, hist = bayes.fit_map_em(p_i, init)
                else:
                    p_i = bayes.problem_for(padded[k])
                    res, h, hist = fits[k]
                per = (time.perf_counter() - t_start) / len(ready)
                out[i] = bayes.after_map(
                    p_i, holds, res, h, hist, base, options, time.perf_counter() - per, record
                )
            except Exception as e:
                out[i] = e
    return out  # type: ignore[return-value]
