"""The plain compiler that callers hand to :mod:`inference` (which compiles nothing itself):
``jit(name, fn)`` compiles ``fn`` in this process only, where the executable store
(:mod:`chekan.runtime.store`, the same ``jit``) would also keep it on disk."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from chekan.runtime.caches import register_weak

__all__ = ["Compiler"]


class Compiler:
    """``jit(name, fn)``: ``fn`` under ``equinox.filter_jit`` (arrays traced, any other leaf
    static), one per name, kept until :meth:`clear` (or :func:`chekan.runtime.clear_caches`).

    A name stands for what its function computes: give each problem, and each sampled
    density, its own compiler. ``traces`` counts the traces of all its functions."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._fns: dict[str, Callable] = {}
        self._traces = [0]  # a list the traced functions hold (not the compiler)
        register_weak(self)

    @property
    def traces(self) -> int:
        return self._traces[0]

    def jit(self, name: str, fn: Callable) -> Callable:
        with self._lock:
            if name not in self._fns:
                import equinox as eqx  # tracing only: a process that loads executables skips it

                self._fns[name] = eqx.filter_jit(_counted(fn, self._traces))
            return self._fns[name]

    def clear(self) -> None:
        with self._lock:
            self._fns.clear()


def _counted(fn: Callable, traces: list[int]) -> Callable:
    def counted(*args: Any) -> Any:
        traces[0] += 1  # a Python side effect: runs once per trace
        return fn(*args)

    return counted
