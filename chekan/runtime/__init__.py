"""The runtime of the estimation code: what is compiled, kept, loaded and cleared.

=================  ==========================================================
module             what it does
=================  ==========================================================
``caches``         every cache registered; one :func:`clear_caches`; ``jit``
``compiler``       the plain compiler handed to ``inference`` (this process only)
``store``          executables compiled once, kept on disk, loaded ever after
``xla``            compiles apart from loads (the store's and JAX's own)
``background``     loads and slow imports in background threads
``process``        the process's executable store and its BLAS threads
``engine``         what is compiled for a joint-model structure; prefetch; first run
``padding``        shape buckets: records of similar size share executables
=================  ==========================================================

The maths (``inference``, ``chekan.joint``'s model modules) compiles nothing of its own:
what runs it jits it here. This package's ``__init__`` imports only the registry, so that
any module may register a cache without importing JAX.
"""

from chekan.runtime.caches import cached, clear_caches, jit, register

__all__ = ["cached", "clear_caches", "jit", "register"]
