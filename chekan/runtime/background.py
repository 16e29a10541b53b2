"""Loads of compiled executables in background threads, with jaxlib's LAPACK kernels bound
first (:mod:`chekan.runtime.store` starts them), and slow imports started ahead of their use."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from typing import Any


def initialise_lapack() -> None:
    """Bind jaxlib's LAPACK kernels (cholesky, svd, …) to their implementations.

    JAX does this when it *lowers* a linear-algebra operation; an executable loaded from a
    file skips lowering, and calling its LAPACK kernels unbound crashes the process
    (segmentation fault, measured on jax 0.10.2). Idempotent.
    """
    from jax._src.lib import lapack

    lapack._lapack.initialize()


def loads_in_background(jobs: list[tuple[Callable, tuple]], threads: int, label: str) -> list[Any]:
    """:func:`in_background` for loads, with LAPACK bound first, in the calling thread.

    Binding imports ``scipy.linalg`` (jaxlib takes the kernels from its Cython capsules).
    Done by a loading thread it raced the caller's own ``import scipy.linalg`` (threadpoolctl
    in :func:`chekan.runtime.process.single_threaded_blas`): the two imports can lock each other's
    submodules, and Python then raises ``_DeadlockError`` in one of them (seen once in a
    ``calibrate_file`` loop). Here the import happens once, before any thread starts.
    """
    if jobs:
        from jax.experimental import serialize_executable  # noqa: F401  (the loader, too)

        from chekan.runtime.xla import guard_jax_compiles

        initialise_lapack()
        guard_jax_compiles()  # here, before a load runs beside this thread's compiles
    return in_background(jobs, threads, label)


def in_background(jobs: list[tuple[Callable, tuple]], threads: int, label: str) -> list[Any]:
    """Run ``fn(*args)`` for each job, in order, on ``threads`` threads; one future per job.

    Not daemon threads: a process that ends while one is inside XLA's deserialiser aborts
    (SIGABRT at exit, measured on jax 0.10.2), so the interpreter waits for them; start
    loads only once the process is likely to use them (after reading its input). They are
    named ``aot-<label>-<i>``: a caller that ends its process itself may recognise them
    (``chekan.files.outputs.DISPOSABLE_THREAD_PREFIX`` relies on that prefix)."""
    import queue
    import threading

    todo: queue.SimpleQueue = queue.SimpleQueue()
    futures: list[Future] = []
    for fn, args in jobs:
        fut: Future = Future()
        futures.append(fut)
        todo.put((fut, fn, args))

    def work() -> None:
        while True:
            try:
                fut, fn, args = todo.get_nowait()
            except queue.Empty:
                return
            if fut.set_running_or_notify_cancel():
                try:
                    fut.set_result(fn(*args))
                except BaseException as e:  # delivered to whoever waits on it
                    fut.set_exception(e)

    for i in range(min(threads, len(jobs))):
        threading.Thread(target=work, name=f"aot-{label}-{i}").start()
    return futures


def imports_in_background(modules: list[str], label: str) -> Future:
    """Import ``modules`` in one background thread, in order; the future of the last.

    For an import that a process will surely need later and that costs it seconds (emcee
    imports ``scipy.stats`` through its KDE move: ≈ 1 s) while its main thread computes
    without importing (the MAP). Python's module locks make a second import of the same
    module wait for the first; but two threads importing *different* modules of one package
    can wait on each other (``_DeadlockError``, see :func:`loads_in_background`), so the
    caller waits on the future before it imports anything more itself.
    """
    import importlib

    def run() -> None:
        for name in modules:
            importlib.import_module(name)

    return in_background([(run, ())], 1, label)[0]
