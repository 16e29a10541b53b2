"""The process's runtime resources: its store of compiled executables and its BLAS threads."""

from __future__ import annotations

from pathlib import Path

from chekan.runtime.caches import cached

__all__ = ["executable_store", "single_threaded_blas"]


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
    from chekan.jaxconfig import cache_folder
    from chekan.runtime.store import ExecutableStore, source_fingerprint

    root = Path(__file__).resolve().parents[2]
    libs = tuple(f"{n}=={_installed_version(n)}" for n in ("equinox", "optimistix", "lineax"))
    fingerprint = source_fingerprint(root / "chekan", root / "inference", extra=libs)
    cache = cache_folder()
    folder = None if cache is None else cache / "executables"
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
