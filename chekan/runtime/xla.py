"""One guard between XLA's compiles and its loads of stored executables, for the store
and, from its first use, for JAX's own compiles too.

JAX offers no hook on its compiles, so :func:`guard_jax_compiles` wraps the module
functions through which it reaches XLA: explicitly, when the guard is first entered (a
store's first load or compile, or a background load starting), never at import.
"""

from __future__ import annotations

import contextlib
import functools
import threading
from collections.abc import Callable

__all__ = ["XLA", "guard_jax_compiles"]


class _LoadsOrCompile:
    """Many loads at once, or one compile (or serialisation) alone.

    Test workers died inside XLA's deserialiser and compiler, beside a compile and beside
    another load; the cause was the process's memory maps running out (``map_budget``,
    docs/tuning.md), not the overlap. Loads share again: 320 loads of the eight largest
    stored executables, two at a time, all succeeded, and a new ``map`` process's three
    loads overlap on two cores (wall ratio 0.89). Compiles stay apart from loads as a
    precaution (XLA's CPU client is not documented to be safe there). A thread that holds
    the compile side may compile again inside it (a store's compile passes through JAX's).
    It guards the library, so there is one per process.
    """

    def __init__(self) -> None:
        self._guarding_jax = False  # JAX's own compiles wrapped (on first entry)
        self._cond = threading.Condition()
        self._loads = 0
        self._owner: int | None = None  # the thread compiling, if any
        self._depth = 0

    def _guard_jax(self) -> None:
        if not self._guarding_jax:
            guard_jax_compiles()
            self._guarding_jax = True

    @contextlib.contextmanager
    def load(self):
        self._guard_jax()
        me = threading.get_ident()
        with self._cond:
            self._cond.wait_for(lambda: self._owner in (None, me))
            self._loads += 1
        try:
            yield
        finally:
            with self._cond:
                self._loads -= 1
                self._cond.notify_all()

    @contextlib.contextmanager
    def alone(self):
        self._guard_jax()
        me = threading.get_ident()
        with self._cond:
            if self._owner != me:
                self._cond.wait_for(lambda: self._owner is None and self._loads == 0)
                self._owner = me
            self._depth += 1
        try:
            yield
        finally:
            with self._cond:
                self._depth -= 1
                if self._depth == 0:
                    self._owner = None
                    self._cond.notify_all()


XLA = _LoadsOrCompile()

#: where JAX itself reaches XLA to compile (``jax.jit``, eager operations, ``Lowered.compile``;
#: older JAX names it ``backend_compile``), to serialise for its persistent cache, and to
#: load from it: (module, function, side of :data:`XLA`)
_JAX_XLA_CALLS = (
    ("jax._src.compiler", "backend_compile_and_load", "alone"),
    ("jax._src.compiler", "backend_compile", "alone"),
    ("jax._src.compilation_cache", "put_executable_and_time", "alone"),
    ("jax._src.compilation_cache", "get_executable_and_time", "load"),
)


_INSTALL = threading.Lock()


def guard_jax_compiles() -> tuple[str, ...]:
    """Put JAX's own compiles and cache writes (alone) and cache loads (shared with loads)
    under :data:`XLA` as the store's are (:class:`_LoadsOrCompile`): its module functions
    are wrapped, once per process (idempotent; the guard calls it when first entered).
    Returns the names guarded (none where this JAX has none of them: then only the store's
    own calls are)."""
    import importlib

    done = []
    for module_name, name, side in _JAX_XLA_CALLS:
        module = importlib.import_module(module_name)
        inner = getattr(module, name, None)
        if inner is None:
            continue
        done.append(f"{module_name}.{name}")
        with _INSTALL:
            if not getattr(getattr(module, name), "guarded_by_chekan", False):
                setattr(module, name, _guarded(inner, side))
    return tuple(done)


def _guarded(inner: Callable, side: str) -> Callable:
    """``inner`` run under :data:`XLA`: ``side`` "alone" (a compile, a serialisation) or
    "load" (a deserialisation, shared with other loads)."""
    enter = getattr(XLA, side)

    @functools.wraps(inner)
    def guarded(*args, **kwargs):
        with enter():
            return inner(*args, **kwargs)

    guarded.guarded_by_chekan = True  # type: ignore[attr-defined]
    return guarded
