"""JAX set-up shared by every module that computes: float64 and the persistent cache.

Import this module before creating any JAX array (``import chekan.jaxconfig``).
1″ is 4.8e-6 rad and 1 − cos θ at small angles is below float32 resolution,
so estimation is float64 throughout.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax


def _cache_dir() -> Path:
    env = os.environ.get("CHEKAN_JAX_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "chekan" / "jax"


jax.config.update("jax_enable_x64", True)
jax.config.update("jax_platforms", os.environ.get("JAX_PLATFORMS", "cpu") or "cpu")
if os.environ.get("CHEKAN_JAX_CACHE", "1") != "0":
    try:
        _dir = _cache_dir()
        _dir.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(_dir))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except OSError:  # read-only home: run without the persistent cache
        pass
