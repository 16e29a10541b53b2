"""MAP of the joint model with EM of the hyperparameters, for one record or a batch.

``MAP_PASSES`` Gauss–Newton solves over θ (β projected out; LM where GN fails). Between
two solves the level reference moves to its estimate and the hyperparameters are
converged at fixed θ (:func:`chekan.joint.em_compiled.between_passes`, one compiled loop;
with ``solver="lm"`` the host loop of 0.2, :func:`chekan.joint.em.between_passes`).

One loop serves a single record (:func:`inference.map.fit_map`) and a batch of records
padded to one structure (:func:`inference.map_batch.fit_map_batch`, vmapped lanes). The solver
returns new state, :class:`MapFit`, with the model whose level reference has moved. How the
constants below were tuned: ``docs/tuning.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from chekan.joint import em, em_compiled
from chekan.joint.engine import problem_for
from chekan.joint.layout import RecordModel
from chekan.joint.problem import Hyper, default_hyper
from inference.map import MapResult, SolverName, fit_map
from inference.map_batch import fit_map_batch

MAP_PASSES = 3  # solves; between them the hyperparameters are converged at fixed θ
SOLVER: SolverName = "gn"  # undamped steps suit the 7-dim, well-started θ (docs/tuning.md)
MAX_STEPS: dict[str, int] = {"gn": 32, "lm": 256}  # a GN pass beyond 32 steps will not converge
MAP_TOL = 1e-8  # the Cauchy test, working units: 3e-11 sd from the 1e-10 answer
MAP_SD_TOL = 1e-4  # GN stops on a Newton decrement below this many posterior sds
MAX_LANES = 2  # vmapped lanes per batch solve (XLA CPU deadlocked at 4)
TAU_RESTARTS_S = (5.0, 120.0)  # other starts of τ for a first pass in the prior's tails
RESTART_APART = 1.5  # a start within this factor of one already tried is skipped
PRIOR_TAIL = 3.0  # |prior z| beyond which a first pass counts as in the tails
RESTART_GAIN = 1.0  # a restart replaces the first pass only if its cost is this much lower


#: a record's τ hint (s) for the first restart, a function that reads it (called only if a
#: restart is needed), or None
TauHint = float | Callable[[], float] | None


@dataclass(frozen=True)
class MapFit:
    """The MAP of one record: the solver's result at θ̂, the hyperparameters at their EM fixed
    point, the passes made, and the model with its level reference at the estimate (what
    the derived quantities and the sampler must use)."""

    result: MapResult
    hyper: Hyper
    history: tuple[dict, ...]
    model: RecordModel


def em_steps(solver: SolverName):
    """The EM between passes that goes with ``solver``, as a module with ``between_passes``
    and ``prefetch``: compiled (:mod:`chekan.joint.em_compiled`) with Gauss–Newton, the host
    EM of 0.2 (:mod:`chekan.joint.em`) with ``"lm"``."""
    return em_compiled if solver == "gn" else em


def fit_map_em(
    model: RecordModel,
    init: dict,
    *,
    progress: bool = False,
    solver: SolverName = SOLVER,
    tau_hint_s: TauHint = None,
) -> MapFit:
    """MAP with EM updates of the hyperparameters for one record (module docstring);
    ``tau_hint_s``: the first τ to restart from if the first pass needs a restart (a
    function is called only then)."""
    hints = None if tau_hint_s is None else [tau_hint_s]
    return fit_map_em_many([model], [init], progress=progress, solver=solver, tau_hints_s=hints)[0]


def fit_map_em_many(
    models: Sequence[RecordModel],
    inits: Sequence[dict],
    *,
    progress: bool = False,
    solver: SolverName = SOLVER,
    tau_hints_s: Sequence[TauHint] | None = None,
) -> list[MapFit]:
    """:func:`fit_map_em` for records of one structure; more than one are solved as a
    batch of vmapped lanes in every pass (pad them first: :meth:`RecordModel.pad`).
    ``tau_hints_s``: each record's first τ to restart from (None: none)."""
    structures = {m.structure for m in models}
    if len(structures) != 1:
        raise ValueError(f"a batch needs one structure (pad the models), got {structures}")
    prob = problem_for(structures.pop())
    models = list(models)
    B = len(models)
    hs = [default_hyper() for _ in range(B)]
    histories: list[list[dict]] = [[] for _ in range(B)]
    results: list[MapResult] = []
    between_passes = em_steps(solver).between_passes
    solvers: list[SolverName] = []  # each record's solver after the first pass (LM where GN failed)
    for it in range(MAP_PASSES):
        args = [(m.data, h) for m, h in zip(models, hs, strict=True)]
        if it == 0:
            results, solvers = _first_pass(prob, args, inits, solver, tau_hints_s)
        else:  # from the previous pass's θ̂
            results, solvers = _solve_pass(prob.lsq, args, [r.z for r in results], solvers)
        for i, res in enumerate(results):
            updates = 0
            if it < MAP_PASSES - 1:
                models[i], hs[i], updates = between_passes(models[i], res.z, hs[i])
            histories[i].append(
                pass_entry(it, res.converged, res.num_steps, res.cost, progress and B == 1, updates)
            )
    return [MapFit(results[i], hs[i], tuple(histories[i]), models[i]) for i in range(B)]


def _apart(tau_s: float, tried_tau_s: Sequence[float]) -> bool:
    """Whether a restart from ``tau_s`` is worth a solve after those from ``tried_tau_s``."""
    return all(abs(math.log(tau_s / t)) > math.log(RESTART_APART) for t in tried_tau_s)


def _in_tails(space, res: MapResult) -> bool:
    """A first pass to try again from other starts: not converged, or in the prior's tails."""
    prior_z = np.abs(np.asarray(space.prior_residuals(np.asarray(res.z))))
    return (not res.converged) or bool(np.any(~np.isfinite(prior_z) | (prior_z > PRIOR_TAIL)))


def _better(new: MapResult, old: MapResult) -> bool:
    """Whether a pass from a later start replaces the one kept so far: a finite cost beats a
    non-finite one, a converged pass a non-converged one, and otherwise only a cost lower
    by more than ``RESTART_GAIN`` (the same mode found again keeps the earlier numbers)."""
    if not np.isfinite(new.cost):
        return False
    if not np.isfinite(old.cost):
        return True
    if new.converged != old.converged:
        return bool(new.converged)
    return bool(new.cost < old.cost - RESTART_GAIN)


def _first_pass(
    prob,
    args: list,
    inits: Sequence[dict],
    solver: SolverName = SOLVER,
    tau_hints_s: Sequence[TauHint] | None = None,
) -> tuple[list[MapResult], list[SolverName]]:
    """The first pass, from several starts where the classical one is not good enough.

    1. ``solver`` from the classical start (τ₀ = 30 s) for every record.
    2. For the records where that pass :func:`_in_tails`: the same solver from the
       record's τ hint, if it has one (the pipeline's is read off the record's settling
       transients, :func:`chekan.joint.start.tau_from_transients`); then from each τ₀ in
       ``TAU_RESTARTS_S``, except for the records whose hint's pass landed in the prior's
       bulk. A τ within a factor ``RESTART_APART`` of one already tried is skipped.
    3. Levenberg–Marquardt (the fallback of a Gauss–Newton pass that did not converge),
       only for the records where no start gave a converged pass inside the prior's bulk,
       from each start whose Gauss–Newton pass did not converge.

    Each record keeps its best pass in start order (:func:`_better`). A short one-round
    session with a fast lag used to run LM from the classical start into a mode where the
    holds never settle (0.1–0.9 s) before the restart from τ₀ = 5 s found the truth in 20 ms.
    Returns the results and each record's solver for the next passes (new lists).
    """
    space, lsq = prob.map_space, prob.lsq
    starts = [[space.to_z(i)] for i in inits]  # starts[i][k]: record i, start k
    tried = [[r] for r in _solve(lsq, args, [s[0] for s in starts], solver)]
    used: list[list[SolverName]] = [[solver] for _ in inits]
    flagged = [i for i, t in enumerate(tried) if _in_tails(space, t[0])]
    taus = [[float(i["tau_s"])] for i in inits]  # τ₀ of each start tried
    hints = list(tau_hints_s) if tau_hints_s is not None else [None] * len(inits)
    rounds: list[list[tuple[int, float]]] = [
        [(i, float(h() if callable(h) else h)) for i in flagged if (h := hints[i]) is not None]
    ]
    rounds += [[(i, tau) for i in flagged] for tau in TAU_RESTARTS_S]
    settled: set[int] = set()  # records whose hint's pass landed in the prior's bulk
    for k, todo in enumerate(rounds):
        which = [(i, t) for i, t in todo if i not in settled and _apart(t, taus[i])]
        if not which:
            continue
        zs = [space.to_z({**inits[i], "tau_s": tau}) for i, tau in which]
        done = _solve(lsq, [args[i] for i, _ in which], zs, solver)
        for (i, tau), z, r in zip(which, zs, done, strict=True):
            starts[i].append(z)
            tried[i].append(r)
            used[i].append(solver)
            taus[i].append(tau)
            if k == 0 and not _in_tails(space, r):
                settled.add(i)
    if solver == "gn":
        redo = [
            (i, k)
            for i in flagged
            if all(_in_tails(space, r) for r in tried[i])
            for k, r in enumerate(tried[i])
            if not r.converged
        ]
        if redo:
            done = _solve(lsq, [args[i] for i, _ in redo], [starts[i][k] for i, k in redo], "lm")
            for (i, k), r in zip(redo, done, strict=True):
                tried[i][k], used[i][k] = r, "lm"
    results, solvers = [], []
    for t, u in zip(tried, used, strict=True):
        best = 0
        for k in range(1, len(t)):
            if _better(t[k], t[best]):
                best = k
        results.append(t[best])
        solvers.append(u[best])
    return results, solvers


def _solve_pass(
    lsq, args: list, zs: list, solvers: list[SolverName]
) -> tuple[list[MapResult], list[SolverName]]:
    """One pass, every record with its solver ("gn" or "lm"), and Levenberg–Marquardt
    from the same start for the records where Gauss–Newton did not converge. Returns the
    results and each record's solver for the next pass: LM where Gauss–Newton failed.

    A record on which Gauss–Newton failed once fails in the later passes too (a record that
    hardly identifies θ, e.g. one short round: measured on every pass of such records), and
    each failure costs its 32 steps before LM starts from the same point.
    """
    results: list[Any] = [None] * len(args)
    after = list(solvers)
    for name in ("gn", "lm"):  # GN first: its failures join the LM solve
        which = [i for i, s in enumerate(after) if s == name]
        if not which:
            continue
        done = _solve(lsq, [args[i] for i in which], [zs[i] for i in which], name)
        for i, r in zip(which, done, strict=True):
            results[i] = r
            if name == "gn" and not r.converged:
                after[i] = "lm"
    return results, after


def map_pass_settings(solver: SolverName) -> dict:
    """The keyword arguments of :func:`inference.map.fit_map` for one MAP pass."""
    decrement = {"sd_tol": MAP_SD_TOL} if solver == "gn" else {}
    return {
        "solver": solver,
        "max_steps": MAX_STEPS[solver],
        "rtol": MAP_TOL,
        "atol": MAP_TOL,
        **decrement,
    }


def _solve(lsq, args: list, zs: list, solver: SolverName) -> list[MapResult]:
    if len(args) == 1:
        return [fit_map(lsq, args[0], zs[0], **map_pass_settings(solver))]
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *args)
    batch = fit_map_batch(
        lsq, stacked, np.stack(zs), max_lanes=MAX_LANES, **map_pass_settings(solver)
    )
    return [batch.item(i) for i in range(len(args))]


def pass_entry(it: int, converged, steps, cost, progress: bool, hyper_updates: int) -> dict:
    """One MAP pass as the result's ``diagnostics.map_passes`` lists it (printed on request)."""
    if progress:
        tail = f", then {hyper_updates} EM updates of the hyperparameters" if hyper_updates else ""
        print(
            f"  MAP pass {it + 1}: {'converged' if converged else 'NOT converged'} "
            f"in {int(steps)} steps, cost {float(cost):.1f}{tail}"
        )
    return {
        "iteration": it,
        "converged": bool(converged),
        "steps": int(steps),
        "cost": float(cost),
        "hyper_updates": int(hyper_updates),
    }
