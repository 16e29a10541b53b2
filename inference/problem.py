r"""A model, as :mod:`inference` sees it: a parameter space and a whitened residual function.

MAP estimation is the nonlinear least-squares problem

.. math::  \hat z = \arg\min_z \tfrac12\lVert r(\theta(z))\rVert^2
            + \tfrac12\lVert r_\text{prior}(z)\rVert^2,

where :math:`r = L^{-1}(y - \mu(\theta))` is the data residual whitened by the noise (so that
:math:`r \sim N(0, I)` at the truth) and :math:`r_\text{prior} = (u - \text{loc})/\text{scale}`.
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from .params import ParamSpace

__all__ = ["Executables", "LeastSquaresProblem"]


class Executables(Protocol):
    """The caller's compiler: ``jit(name, fn)`` returns ``fn`` compiled (and kept, where the
    caller keeps executables: ``chekan.runtime.store.ExecutableStore``). This package
    compiles nothing of its own through it."""

    def jit(self, name: str, fn: Callable) -> Callable: ...


@dataclass(frozen=True, eq=False)
class LeastSquaresProblem:
    r"""MAP as nonlinear least squares: minimise :math:`\tfrac12\lVert r\rVert^2 +
    \tfrac12\lVert r_\text{prior}\rVert^2`.

    ``residuals(values, data)`` returns the whitened data residual vector (fixed length for
    given data shapes; padded entries must be exactly 0). It must be a pure JAX function.
    Equality and hashing are by identity. Its compiler keeps the compiled solvers: build the
    problem once and reuse it.
    """

    space: ParamSpace
    residuals: Callable[[dict[str, Array], Any], Array]
    executables: Executables
    """What compiles the solvers and keeps them (the caller's: a compiler of its own per
    problem, or an executable store whose fingerprint covers the code of ``residuals``)."""

    def __post_init__(self) -> None:
        if not isinstance(self.space, ParamSpace):
            raise TypeError(f"space must be a ParamSpace, got {type(self.space).__name__}")
        if not callable(self.residuals):
            raise TypeError("residuals must be a callable (values, data) -> residual vector")

    def data_residuals(self, z: ArrayLike, data: Any) -> Array:
        """Whitened data residuals at ``z``, flattened to a vector."""
        r = jnp.asarray(self.residuals(self.space.to_values(z), data))
        return r.reshape(-1)

    def stacked_residuals(self, z: ArrayLike, data: Any) -> Array:
        """``concat(data residuals, prior residuals)``: the vector whose squared norm is 2·cost."""
        return stacked_residuals_of(self.space, self.residuals, z, data)

    def cost(self, z: ArrayLike, data: Any) -> Array:
        r"""½‖stacked residuals‖² (the negative log posterior up to a constant)."""
        r = self.stacked_residuals(z, data)
        return 0.5 * jnp.sum(r**2)

    def log_density(self, z: ArrayLike, data: Any) -> Array:
        r"""Log posterior over :math:`z` up to a constant independent of :math:`z`:
        :math:`-\tfrac12\lVert r\rVert^2 + \log p(u)`.

        Valid for sampling only when the whitening does not depend on sampled parameters (fixed
        noise). Sampled noise scales need the :math:`-\sum\log\sigma` term: write the
        log-density yourself.
        """
        r = self.data_residuals(z, data)
        return -0.5 * jnp.sum(r**2) + self.space.log_prior(z)


def stacked_residuals_of(space: ParamSpace, residuals: Callable, z: ArrayLike, data: Any) -> Array:
    """:meth:`LeastSquaresProblem.stacked_residuals` from the problem's space and residual
    function alone. A solver is handed this (bound to the two, not the problem's method):
    JAX keeps the static leaves of what it traced in a process-wide cache, and a bound
    method there kept the problem, its executable store and every executable in it alive."""
    r = jnp.asarray(residuals(space.to_values(z), data)).reshape(-1)
    return jnp.concatenate([r, space.prior_residuals(z)])
