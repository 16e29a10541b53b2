"""Every cache of the process, registered in one place: :func:`clear_caches` forgets them
all (equinox's ``_caches.py`` pattern).

A cache is made here (:func:`cached`, :func:`jit`) or handed its clear function
(:func:`register`); nothing else in the package keeps compiled code or what it computed.
"""

from __future__ import annotations

import functools
import threading
import weakref
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

_LOCK = threading.Lock()
#: the clear functions of every live cache (a weak reference to a jitted function's: one
#: dropped with what held it leaves the registry)
_CLEARS: list[Callable[[], Callable[[], None] | None]] = []


def register(clear: Callable[[], None]) -> Callable[[], None]:
    """Add ``clear`` (a cache's clear function) to what :func:`clear_caches` calls; returns it."""
    with _LOCK:
        _CLEARS.append(lambda: clear)
    return clear


def cached(fn: F | None = None, *, maxsize: int | None = None) -> Any:
    """``functools.lru_cache(maxsize)`` (unbounded: None) of ``fn``, registered."""

    def wrap(f: F) -> F:
        out = functools.lru_cache(maxsize=maxsize)(f)
        register(out.cache_clear)
        return out  # type: ignore[return-value]

    return wrap if fn is None else wrap(fn)


def jit(fn: Callable | None = None, **options: Any) -> Any:
    """``jax.jit(fn, **options)``, its cache of compiled code registered (weakly: a jitted
    function made inside another cache goes with it)."""

    def wrap(f: Callable) -> Callable:
        import jax

        out = jax.jit(f, **options)
        ref = weakref.ref(out)
        with _LOCK:
            _CLEARS.append(lambda: getattr(ref(), "clear_cache", None))
        return out

    return wrap if fn is None else wrap(fn)


def register_weak(owner: Any) -> Any:
    """Add ``owner.clear`` to what :func:`clear_caches` calls, for as long as ``owner`` lives
    (a compiler that a problem holds goes with the problem); returns ``owner``."""
    ref = weakref.ref(owner)
    with _LOCK:
        _CLEARS.append(lambda: getattr(ref(), "clear", None))
    return owner


def clear_caches() -> None:
    """Forget every registered cache (compiled functions, engines, stores' handles; files
    on disk stay). Call before ``jax.clear_caches()`` where JAX's own should go too."""
    with _LOCK:
        live = [(get, get()) for get in _CLEARS]
        _CLEARS[:] = [get for get, clear in live if clear is not None]
    for _, clear in live:
        if clear is not None:
            clear()


def registered() -> int:
    """How many caches are registered (live ones; for tests)."""
    with _LOCK:
        return sum(get() is not None for get in _CLEARS)
