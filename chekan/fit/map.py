"""MAP of the joint model with EM of the hyperparameters, for one record.

``MAP_PASSES`` Gauss–Newton solves over θ (β projected out; LM where GN fails). Between
two solves the level reference moves to its estimate and the hyperparameters are
converged at fixed θ (:func:`between_passes`: :mod:`chekan.joint.em`'s compiled loop, whatever
the passes' solver).

Each pass is one :func:`inference.map.fit_map`. The fit returns new state, :class:`MapFit`,
with the model whose level reference has moved. How the constants below were tuned:
``docs/tuning.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from chekan.jaxconfig import device_array
from chekan.joint.em import HYPER_TOL, still_moving, to_zero
from chekan.joint.layout import RecordModel
from chekan.joint.problem import Hyper, default_hyper
from chekan.runtime.engine import engine_for, problem_for
from inference.map import MapResult, SolverName, fit_map

MAP_PASSES = 3  # solves; between them the hyperparameters are converged at fixed θ
SOLVER: SolverName = "gn"  # undamped steps suit the 7-dim, well-started θ (docs/tuning.md)
MAX_STEPS: dict[str, int] = {"gn": 32, "lm": 256}  # a GN pass beyond 32 steps will not converge
MAP_TOL = 1e-8  # the Cauchy test, working units: 3e-11 sd from the 1e-10 answer
MAP_SD_TOL = 1e-4  # GN stops on a Newton decrement below this many posterior sds
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

    @property
    def capped_passes(self) -> list[int]:
        """The passes (1-based) after which the EM of the hyperparameters stopped at its cap
        still moving (not towards zero)."""
        return [p["iteration"] + 1 for p in self.history if p.get("hyper_converged") is False]

    @property
    def converged(self) -> bool:
        """Whether the MAP converged, its hyperparameters' EM included: no pass may end with
        the EM at its cap, whether still moving or creeping down to a variance of zero
        (then the variance is not at its estimate either)."""
        capped = self.capped_passes or any(p.get("hyper_to_zero") for p in self.history)
        return bool(self.result.converged) and not capped


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
    prob = problem_for(model.structure)
    h = default_hyper()
    history: list[dict] = []
    res, pass_solver = _first_pass(prob, (model.data, h), init, solver, tau_hint_s)
    for it in range(MAP_PASSES):
        if it > 0:  # from the previous pass's θ̂, with its solver (LM where GN failed)
            res, pass_solver = _solve_pass(prob.lsq, (model.data, h), res.z, pass_solver)
        updates, moving = 0, cast(tuple[tuple[str, float], ...], ())
        if it < MAP_PASSES - 1:
            model, h, updates, moving = between_passes(model, res.z, h)
        history.append(
            pass_entry(it, res.converged, res.num_steps, res.cost, progress, updates, moving)
        )
    return MapFit(res, h, tuple(history), model)


def between_passes(
    model: RecordModel, z, h: Hyper
) -> tuple[RecordModel, Hyper, int, tuple[tuple[str, float], ...]]:
    """What follows every MAP pass but the last, compiled (:func:`chekan.joint.em.em_pass_fn`):
    the model with its level moved to the estimate (m_ref ← m_ref + ĉ), the hyperparameters
    at their EM fixed point given θ = z, the number of EM updates, and the hyperparameters
    that EM still moved where it stopped at ``HYPER_MAX_UPDATES`` (name and move in log;
    empty: converged; :func:`chekan.joint.em.still_moving`).

    The equilibrium Eₖ is computed about m_ref (b is dG/dm there) while c only shifts the
    readings; the classical m_h that m_ref starts from is biased where the level holds have
    not settled (17 pix at τ = 90 s on the 3 h program), and that bias went into b (≈ +0.5
    sd). After one pass ĉ is known to ~0.01 pix, so the next pass works about the estimate.

    Where EM has not converged after ``EM_UPDATES_BEFORE_NEWTON`` updates the fixed point is
    solved for by a second compiled function (:func:`chekan.joint.em.em_newton_fn`): records
    whose EM converges never compile or load it (it is most of the EM's code).
    """
    engine = engine_for(model.structure)
    m_ref, h_new, n, change = engine.em_pass(device_array(z), h, model.data)
    moved = model.with_level(np.asarray(m_ref))
    moving: tuple[tuple[str, float], ...] = ()
    if float(change) >= HYPER_TOL:
        h_new, n, change, step = engine.em_newton(device_array(z), h_new, n, change, moved.data)
        moving = still_moving(step) if float(change) >= HYPER_TOL else ()
    return moved, h_new, int(n), moving


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
    prob, args: tuple, init: dict, solver: SolverName = SOLVER, tau_hint_s: TauHint = None
) -> tuple[MapResult, SolverName]:
    """The first pass, from several starts where the classical one is not good enough.

    1. ``solver`` from the classical start (τ₀ = 30 s).
    2. If that pass :func:`_in_tails`: the same solver from the record's τ hint, if it has
       one (the pipeline's is read off the record's settling transients,
       :func:`chekan.classical.settling.tau_from_transients`); then, unless the hint's pass landed
       in the prior's bulk, from each τ₀ in ``TAU_RESTARTS_S``. A τ within a factor
       ``RESTART_APART`` of one already tried is skipped.
    3. Levenberg–Marquardt (the fallback of a Gauss–Newton pass that did not converge),
       only if no start gave a converged pass inside the prior's bulk, from each start
       whose Gauss–Newton pass did not converge.

    The best pass in start order is kept (:func:`_better`). A short one-round session with
    a fast lag used to run LM from the classical start into a mode where the holds never
    settle (0.1–0.9 s) before the restart from τ₀ = 5 s found the truth in 20 ms. Returns
    the pass and the solver for the next passes.
    """
    space, lsq = prob.map_space, prob.lsq
    z0 = space.to_z(init)
    tried = [_Start(z0, _solve(lsq, args, z0, solver), solver)]
    if _in_tails(space, tried[0].result):
        taus = [float(init["tau_s"])]  # τ₀ of each start tried

        def restart(tau: float) -> MapResult:
            z = space.to_z({**init, "tau_s": tau})
            tried.append(_Start(z, _solve(lsq, args, z, solver), solver))
            taus.append(tau)
            return tried[-1].result

        restarts = list(TAU_RESTARTS_S)
        if tau_hint_s is not None:
            hint = float(tau_hint_s() if callable(tau_hint_s) else tau_hint_s)
            if _apart(hint, taus) and not _in_tails(space, restart(hint)):
                restarts = []  # the hint's pass landed in the prior's bulk
        for tau in restarts:
            if _apart(tau, taus):
                restart(tau)
        if solver == "gn" and all(_in_tails(space, t.result) for t in tried):
            tried = [
                t if t.result.converged else _Start(t.z, _solve(lsq, args, t.z, "lm"), "lm")
                for t in tried
            ]
    best = tried[0]
    for t in tried[1:]:
        if _better(t.result, best.result):
            best = t
    return best.result, best.solver


@dataclass(frozen=True)
class _Start:
    """One start of the first pass: the start, the pass from it and the solver it used."""

    z: np.ndarray
    result: MapResult
    solver: SolverName


def _solve_pass(lsq, args: tuple, z, solver: SolverName) -> tuple[MapResult, SolverName]:
    """One pass with ``solver``, and Levenberg–Marquardt from the same start where
    Gauss–Newton did not converge. Returns the pass and the solver for the next pass: LM
    where Gauss–Newton failed.

    A record on which Gauss–Newton failed once fails in the later passes too (a record that
    hardly identifies θ, e.g. one short round: measured on every pass of such records), and
    each failure costs its 32 steps before LM starts from the same point.
    """
    res = _solve(lsq, args, z, solver)
    if solver == "gn" and not res.converged:
        return _solve(lsq, args, z, "lm"), "lm"
    return res, solver


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


def _solve(lsq, args: tuple, z, solver: SolverName) -> MapResult:
    """One MAP pass of ``solver`` from ``z`` (:func:`inference.map.fit_map`)."""
    return fit_map(lsq, args, z, **map_pass_settings(solver))


def pass_entry(
    it: int,
    converged,
    steps,
    cost,
    progress: bool,
    hyper_updates: int,
    moving: tuple[tuple[str, float], ...] = (),
) -> dict:
    """One MAP pass as the result's ``diagnostics.map_passes`` lists it (printed on request).
    ``moving``: what EM still moved at its cap; creeping down to a variance of zero
    (:func:`chekan.joint.em.to_zero`) adds ``hyper_to_zero`` (their names), anything else
    ``hyper_converged`` False."""
    down = to_zero(moving)
    if progress:
        tail = f", then {hyper_updates} EM updates of the hyperparameters" if hyper_updates else ""
        if moving:
            names = ", ".join(n for n, _ in moving)
            tail += (
                f" ({names} creeping to zero at the cap)"
                if down
                else f" (EM NOT converged: stopped at its cap, {names} still moving)"
            )
        print(
            f"  MAP pass {it + 1}: {'converged' if converged else 'NOT converged'} "
            f"in {int(steps)} steps, cost {float(cost):.1f}{tail}"
        )
    entry = {
        "iteration": it,
        "converged": bool(converged),
        "steps": int(steps),
        "cost": float(cost),
        "hyper_updates": int(hyper_updates),
    }
    if down:
        return {**entry, "hyper_to_zero": [n for n, _ in moving]}
    return {**entry, "hyper_converged": False} if moving else entry
