"""The compiled engine of the joint model: everything that is compiled for one
:class:`~chekan.joint.layout.ModelStructure`, under one roof, with what starts its loads
and the notice of a first run that compiles.

==========================  ==========================================  ==========================
stored name                 what it computes                            maths in
==========================  ==========================================  ==========================
``map_<solver>_…``          the MAP solve over θ (β projected out)      :mod:`chekan.joint.problem`
``em_between_passes``       level re-centring and EM between passes     :mod:`chekan.joint.em`
``em_newton``               EM's fixed point by Newton, else SQUAREM    :mod:`chekan.joint.em`
``map_derived``             derived quantities and their Jacobians      :mod:`chekan.joint.derived`
``draws``                   every reported quantity per posterior draw  :mod:`chekan.joint.derived`
``predictive_equilibria``   equilibria of the posterior predictive      :mod:`chekan.joint.derived`
==========================  ==========================================  ==========================

An :class:`Engine` per structure (:func:`engine_for`, the one cache of the joint model)
holds the problem and the compiled functions, built on first use and kept in the
executable store (:mod:`chekan.runtime.store`, scoped by the structure), so that records
of one structure share them and a new process loads instead of tracing. Per-record numbers
(duration, counts) are arguments of the compiled functions, never part of their keys.
:func:`chekan.runtime.clear_caches` forgets them, with every other registered cache. The
model modules stay pure maths: each gives the function to compile, the engine compiles it;
what runs them on a record stands above the engine (:func:`chekan.fit.map.between_passes`,
:mod:`chekan.fit.reported`, :mod:`chekan.fit.predictive`), so no module that the engine
compiles from imports it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from chekan.runtime.caches import cached, clear_caches
from chekan.runtime.process import executable_store

if TYPE_CHECKING:  # the joint model is imported where it is used: it imports this module
    from chekan.joint.layout import ModelStructure, RecordData, RecordModel
    from chekan.joint.problem import CalibrationProblem

EM_PASS = "em_between_passes"
EM_NEWTON = "em_newton"
MAP_DERIVED = "map_derived"
DRAWS = "draws"
PREDICTIVE = "predictive_equilibria"


@dataclass(frozen=True, eq=False)
class Engine:
    """The problem and the compiled functions of one structure (module docstring)."""

    structure: ModelStructure
    problem: CalibrationProblem
    store: Any  # chekan.runtime.store.ExecutableStore, scoped by the structure

    @functools.cached_property
    def em_pass(self) -> Callable:
        """``(z, h, data) → (m_ref, h, updates, change)``: :func:`chekan.joint.em.em_pass_fn`."""
        from chekan.joint.em import em_pass_fn

        return self.store.jit(EM_PASS, em_pass_fn(self.structure, self.problem.map_space))

    @functools.cached_property
    def em_newton(self) -> Callable:
        """``(z, h, updates, change, data) → (h, updates, change, step)``:
        :func:`chekan.joint.em.em_newton_fn`."""
        from chekan.joint.em import em_newton_fn

        return self.store.jit(EM_NEWTON, em_newton_fn(self.structure, self.problem.map_space))

    @functools.cached_property
    def map_derived(self) -> Callable:
        """``(z, h, data, duration_h) →`` derived quantities:
        :func:`chekan.joint.derived.map_derived_fn`."""
        from chekan.joint.derived import map_derived_fn

        return self.store.jit(MAP_DERIVED, map_derived_fn(self.structure, self.problem.map_space))

    @functools.cached_property
    def draws(self) -> Callable:
        """``(zs, keys, data, duration_h) →`` named draws: :func:`chekan.joint.derived.draws_fn`."""
        from chekan.joint.derived import draws_fn

        return self.store.jit(DRAWS, draws_fn(self.structure, self.problem.bayes_space))

    @functools.cached_property
    def predictive(self) -> Callable:
        """``(sensor params, tx, ty) →`` equilibria: :func:`chekan.joint.derived.equilibria_of`."""
        from chekan.joint.derived import equilibria_of

        return self.store.jit(PREDICTIVE, equilibria_of)

    def prefetch(self, name: str, data: RecordData, *extra) -> None:
        """Start loading the stored executable ``name`` (a MAP-side one: ``(z, h, data,
        *extra)``) in the background; z on the host (``jnp.zeros`` would compile an executable
        in a new process, 20 ms)."""
        self.store.prefetch(name, *self._map_side_args(data, *extra))

    def stored(self, name: str, data: RecordData, *extra) -> bool:
        """Whether the MAP-side executable ``name`` for ``data`` would be loaded, not
        compiled (as :meth:`prefetch`)."""
        return self.store.stored(name, *self._map_side_args(data, *extra))

    def _map_side_args(self, data: RecordData, *extra) -> tuple:
        from chekan.joint.problem import default_hyper

        return (np.zeros(self.problem.map_space.size), default_hyper(), data, *extra)


@cached
def engine_for(structure: ModelStructure) -> Engine:
    """The :class:`Engine` of ``structure``, built once per process (until
    :func:`clear_caches`)."""
    from chekan.joint.problem import build_problem

    store = executable_store().scoped(repr(structure))
    return Engine(structure, build_problem(structure, store), store)


def problem_for(structure: ModelStructure) -> CalibrationProblem:
    """The MAP least-squares problem and the marginal log-density of ``structure``."""
    return engine_for(structure).problem


FIRST_RUN_NOTICE = (
    "compiling the joint model for this record's shape, its first run with this code (up to "
    "a minute or two on 2 cores; later runs load it)"
)


def compiled_before(model: RecordModel) -> bool:
    """Whether this structure's EM pass is stored (or loaded): False on the first run of a
    tilt program (a new model structure), which compiles its executables before it computes
    (:data:`FIRST_RUN_NOTICE` says so first)."""
    return engine_for(model.structure).stored(EM_PASS, model.data)


def prefetch_em(model: RecordModel) -> None:
    """Start loading this structure's stored EM pass in the background (what follows the
    first MAP pass: :func:`chekan.fit.map.between_passes`)."""
    engine_for(model.structure).prefetch(EM_PASS, model.data)


def prefetch_after_map(model: RecordModel, method: str) -> Future | None:
    """Start what ``method`` needs after the MAP, while the MAP runs: for ``map`` the stored
    derived quantities (:func:`chekan.fit.reported.map_derived`); for ``bayes`` the
    sampler's imports (emcee → scipy.stats, ≈ 1 s; arviz for the Pareto-smoothed weights,
    ≈ 2 s), whose future is returned: wait on it
    before the calling thread imports more (deadlock-free)."""
    if method == "map":
        engine_for(model.structure).prefetch(MAP_DERIVED, model.data, model.duration_h)
        return None
    from chekan.runtime.background import imports_in_background, initialise_lapack

    initialise_lapack()  # its import of scipy.linalg first: the MAP's thread imports no more
    return imports_in_background(["emcee", "inference.sampling", "arviz"], "imports")


__all__ = [
    "FIRST_RUN_NOTICE",
    "Engine",
    "clear_caches",
    "compiled_before",
    "engine_for",
    "prefetch_after_map",
    "prefetch_em",
    "problem_for",
]
