"""JAX set-up for :mod:`inference`: float64 everywhere.

Imported first by every module of the package, before any array exists. Whitened residuals of
precise measurements and Cholesky factors of near-singular normal matrices need float64; JAX
defaults to float32 without this flag.
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)
