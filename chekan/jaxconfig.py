"""JAX set-up shared by every module that computes: float64 and the persistent cache (the
store of compiled executables and the BLAS threads: :mod:`chekan.runtime.process`).

Import this module before creating any JAX array (``import chekan.jaxconfig``).
1″ is 4.8e-6 rad and 1 − cos θ at small angles is below float32 resolution,
so estimation is float64 throughout.

``CHEKAN_JAX_CACHE``: unset, empty or ``1`` — the default folder
(``$XDG_CACHE_HOME/chekan/jax``, else ``~/.cache/chekan/jax``); ``0`` — no persistent
cache and no stored executables; anything else — that folder. Compiled executables
(:mod:`chekan.runtime.store`) are kept in its ``executables`` sub-folder.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import jax
import numpy as np


def cache_dir() -> Path | None:
    """The persistent cache folder (None: disabled by ``CHEKAN_JAX_CACHE=0``)."""
    env = os.environ.get("CHEKAN_JAX_CACHE", "")
    if env == "0":
        return None
    if env and env != "1":
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "chekan" / "jax"


jax.config.update("jax_enable_x64", True)
jax.config.update("jax_platforms", os.environ.get("JAX_PLATFORMS", "cpu") or "cpu")
_CACHE = cache_dir()
if _CACHE is not None:
    try:
        _CACHE.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(_CACHE))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except OSError:  # read-only home: run without the persistent cache
        _CACHE = None


def cache_folder() -> Path | None:
    """The persistent cache folder in use (None: off, or not writable)."""
    return _CACHE


def device_array(x, dtype=None) -> jax.Array:
    """``x`` (array-like) as a JAX array, placed without dispatching an operation.

    ``jnp.asarray`` stages a ``convert_element_type`` for every new shape and dtype, and in
    a new process each one compiles (≈ 15 ms): 0.6 s over the ~50 arrays of one record
    (measured, jax 0.10.2). ``device_put`` of the NumPy array gives the same array (same
    dtype, not weakly typed).
    """
    return jax.device_put(np.asarray(x, dtype=dtype))


def device_arrays(tree: dict[str, Any]) -> dict[str, jax.Array]:
    """Every leaf of ``tree`` (NumPy arrays) as a JAX array, placed in one call
    (:func:`device_array` leaf by leaf costs ~0.1 ms each)."""
    return jax.device_put(tree)
