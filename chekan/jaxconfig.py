"""JAX set-up shared by every module that computes: float64, the persistent cache and the
store of compiled executables.

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

from chekan.runtime import cached


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


def single_threaded_blas():
    """A context in which OpenBLAS (NumPy's, SciPy's, and the LAPACK kernels JAX's CPU
    Cholesky and SVD call) runs on one thread.

    The model's matrices are small (≈ 134 × 134): OpenBLAS's thread pool costs more than it
    gives, and with another process on the cores it stalls. Measured on 2 cores under
    load: one Cholesky 5 ms with the pool, 0.08 ms without; a MAP residual 17 → 3 ms.
    Scoped (``threadpoolctl``), not a process-wide setting: estimation enters it.
    """
    return _blas_controller().limit(limits=1, user_api="blas")


@cached
def _blas_controller():
    """The BLAS libraries of this process, found once: ``threadpool_limits`` searches the
    loaded libraries on every call (7 ms, a twentieth of a short session's MAP). SciPy is
    imported first so that its OpenBLAS (the one JAX's LAPACK kernels call) is among them."""
    import scipy.linalg  # noqa: F401
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@cached
def executable_store():
    """The store of compiled executables of the estimation code (:mod:`chekan.runtime.store`),
    fingerprinted by the source of ``chekan`` and ``inference`` and the versions of the
    libraries they trace through; in memory only when the cache is off."""
    from chekan.runtime.store import ExecutableStore, source_fingerprint

    root = Path(__file__).resolve().parents[1]
    libs = tuple(f"{n}=={_installed_version(n)}" for n in ("equinox", "optimistix", "lineax"))
    fingerprint = source_fingerprint(root / "chekan", root / "inference", extra=libs)
    folder = None if _CACHE is None else _CACHE / "executables"
    return ExecutableStore(folder, fingerprint)


def _installed_version(name: str) -> str:
    """The installed version of distribution ``name``, from its METADATA's ``Version:`` line:
    ``importlib.metadata.version`` parses the whole file as e-mail headers (≈ 15 ms for
    these three, a new process's start-up); it is the fallback where that line is missing."""
    from importlib.metadata import distribution

    dist = distribution(name)
    text = dist.read_text("METADATA") or ""
    found = (line[9:].strip() for line in text.splitlines() if line.startswith("Version: "))
    return next(found, None) or dist.version


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
