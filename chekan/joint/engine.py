"""The compiled engine of the joint model: everything that is compiled for one
:class:`~chekan.joint.layout.ModelStructure`, under one roof.

==========================  ==========================================  =======================
stored name                 what it computes                            maths in
==========================  ==========================================  =======================
``map_<solver>_…``          the MAP solve over θ (β projected out)      :mod:`.problem`
``em_between_passes``       level re-centring and EM between passes     :mod:`.em`
``em_newton``               EM's fixed point by Newton (EM creeping)    :mod:`.em`
``map_derived``             derived quantities and their Jacobians      :mod:`.derived`
``draws``                   every reported quantity per posterior draw  :mod:`.derived`
``predictive_equilibria``   equilibria of the posterior predictive      :mod:`.derived`
==========================  ==========================================  =======================

An :class:`Engine` per structure (:func:`engine_for`, the one cache of the joint model)
holds the problem and the compiled functions, built on first use and kept in the
executable store (:mod:`chekan.runtime.store`, scoped by the structure), so that records of one
structure share them and a new process loads instead of tracing. Per-record numbers
(duration, counts) are arguments of the compiled functions, never part of their keys.
:func:`chekan.runtime.clear_caches` forgets them, with every other registered cache. The
model modules stay pure maths: each gives the function to compile, the engine compiles it;
what runs them on a record stands above the engine (:func:`chekan.joint.map.between_passes`,
:mod:`chekan.joint.reported`, :mod:`chekan.joint.predictive`), so no module that the engine
compiles from imports it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from chekan.jaxconfig import executable_store
from chekan.joint.layout import ModelStructure, RecordData
from chekan.joint.problem import CalibrationProblem, build_problem, default_hyper
from chekan.runtime import cached, clear_caches

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
        """``(z, h, data) → (m_ref, h, updates, change)``: :func:`.em.em_pass_fn`."""
        from chekan.joint.em import em_pass_fn

        return self.store.jit(EM_PASS, em_pass_fn(self.structure, self.problem.map_space))

    @functools.cached_property
    def em_newton(self) -> Callable:
        """``(z, h, updates, change, data) → (h, updates)``: :func:`.em.em_newton_fn`."""
        from chekan.joint.em import em_newton_fn

        return self.store.jit(EM_NEWTON, em_newton_fn(self.structure, self.problem.map_space))

    @functools.cached_property
    def map_derived(self) -> Callable:
        """``(z, h, data, duration_h) →`` derived quantities: :func:`.derived.map_derived_fn`."""
        from chekan.joint.derived import map_derived_fn

        return self.store.jit(MAP_DERIVED, map_derived_fn(self.structure, self.problem.map_space))

    @functools.cached_property
    def draws(self) -> Callable:
        """``(zs, keys, data, duration_h) →`` named draws: :func:`.derived.draws_fn`."""
        from chekan.joint.derived import draws_fn

        return self.store.jit(DRAWS, draws_fn(self.structure, self.problem.bayes_space))

    @functools.cached_property
    def predictive(self) -> Callable:
        """``(sensor params, tx, ty) →`` equilibria: :func:`.derived.equilibria_of`."""
        from chekan.joint.derived import equilibria_of

        return self.store.jit(PREDICTIVE, equilibria_of)

    def prefetch(self, name: str, data: RecordData, *extra) -> None:
        """Start loading the stored executable ``name`` (a MAP-side one: ``(z, h, data,
        *extra)``) in the background; z on the host (``jnp.zeros`` would compile a program
        in a new process, 20 ms)."""
        self.store.prefetch(name, *self._map_side_args(data, *extra))

    def stored(self, name: str, data: RecordData, *extra) -> bool:
        """Whether the MAP-side executable ``name`` for ``data`` would be loaded, not
        compiled (as :meth:`prefetch`)."""
        return self.store.stored(name, *self._map_side_args(data, *extra))

    def _map_side_args(self, data: RecordData, *extra) -> tuple:
        return (np.zeros(self.problem.map_space.size), default_hyper(), data, *extra)


@cached
def engine_for(structure: ModelStructure) -> Engine:
    """The :class:`Engine` of ``structure``, built once per process (until
    :func:`clear_caches`)."""
    store = executable_store().scoped(repr(structure))
    return Engine(structure, build_problem(structure, store), store)


def problem_for(structure: ModelStructure) -> CalibrationProblem:
    """The MAP least-squares problem and the marginal log-density of ``structure``."""
    return engine_for(structure).problem


__all__ = ["Engine", "clear_caches", "engine_for", "problem_for"]
