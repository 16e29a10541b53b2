r"""Named parameters and the flat, O(1)-scaled working vector the solvers and samplers see.

Every parameter element has an *unconstrained* value :math:`u` and a *constrained* value

.. math::  v = u \quad(\text{identity}) \qquad\text{or}\qquad v = e^{u} \quad(\text{log}).

The prior, when present, is Gaussian on :math:`u`: :math:`u \sim N(\text{loc}, \text{scale}^2)`
(``scale = inf`` means flat: no prior term). Solvers and samplers work on

.. math::  z = (u - \text{loc}) / \text{typical},

so that every coordinate of :math:`z` is O(1) (Levenberg–Marquardt does no column scaling, and
the sampler's initial ball is isotropic-ish). :math:`u \mapsto z` is affine, so a density over
:math:`z` equals the density over :math:`u` up to a constant: no Jacobian term is needed.
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

__all__ = ["Param", "ParamSpace", "flat_element_names"]

_TRANSFORMS = ("identity", "log")
_LOG_2PI = math.log(2.0 * math.pi)


def flat_element_names(name: str, shape: tuple[int, ...]) -> list[str]:
    """Names of the elements of a parameter: ``"b"`` (scalar), ``"b[2]"``, ``"b[1,0]"``."""
    if shape == ():
        return [name]
    return [f"{name}[{','.join(map(str, idx))}]" for idx in np.ndindex(*shape)]


@dataclass(frozen=True)
class Param:
    """One named (scalar or array) parameter.

    ``loc``/``scale``: Gaussian prior on the unconstrained value ``u`` (``scale=inf``: flat).
    ``transform``: ``"identity"`` (value = u) or ``"log"`` (value = exp(u), for positive
    quantities). ``typical``: size of ``u``'s uncertainty used to scale the working vector,
    ``z = (u - loc)/typical``; defaults to ``scale`` if finite, else 1.
    """

    name: str
    loc: float = 0.0
    scale: float = math.inf
    transform: str = "identity"
    shape: tuple[int, ...] = ()
    typical: float | None = None
    unit: str = ""
    doc: str = ""

    def __post_init__(self) -> None:
        if not self.name or not self.name.isidentifier():
            raise ValueError(f"Param name {self.name!r} must be a Python identifier")
        if self.transform not in _TRANSFORMS:
            raise ValueError(
                f"Param {self.name!r}: transform {self.transform!r} is not one of {_TRANSFORMS}"
            )
        if not math.isfinite(self.loc):
            raise ValueError(f"Param {self.name!r}: loc must be finite, got {self.loc}")
        if not (self.scale > 0):
            raise ValueError(
                f"Param {self.name!r}: scale must be > 0 (math.inf for a flat prior), "
                f"got {self.scale}"
            )
        if self.typical is not None and not (0 < self.typical < math.inf):
            raise ValueError(
                f"Param {self.name!r}: typical must be finite and > 0, got {self.typical}"
            )
        shape = tuple(int(n) for n in self.shape)
        if any(n < 0 for n in shape):
            raise ValueError(f"Param {self.name!r}: negative dimension in shape {self.shape}")
        object.__setattr__(self, "shape", shape)

    @property
    def size(self) -> int:
        """Number of scalar elements."""
        return math.prod(self.shape)

    @property
    def step(self) -> float:
        """The scale of the working vector: ``u = loc + step * z``."""
        if self.typical is not None:
            return float(self.typical)
        return float(self.scale) if math.isfinite(self.scale) else 1.0

    @property
    def has_prior(self) -> bool:
        """True when the prior on ``u`` is proper (finite ``scale``)."""
        return math.isfinite(self.scale)


class ParamSpace:
    r"""Maps the flat working vector :math:`z` to named constrained values and back.

    ``u = loc + typical * z`` element-wise; ``value = u`` or ``exp(u)``. All methods that take
    ``z`` are jit/vmap-safe and accept leading batch axes ``z.shape == (..., size)``. They
    return JAX arrays for JAX inputs (and tracers) and NumPy arrays for anything else, so that
    host-side bookkeeping does not pay JAX's per-operation dispatch and compile cost.
    """

    def __init__(self, params: Sequence[Param]):
        params = tuple(params)
        names = [p.name for p in params]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"duplicate parameter names: {dupes}")
        self.params: tuple[Param, ...] = params
        self.names: tuple[str, ...] = tuple(names)
        self.slices: dict[str, slice] = {}
        start = 0
        for p in params:
            self.slices[p.name] = slice(start, start + p.size)
            start += p.size
        self.size: int = start
        self._by_name = {p.name: p for p in params}
        # Element-wise constants (NumPy: they become literals inside jit).
        self._loc = np.concatenate([np.full(p.size, p.loc) for p in params] or [np.zeros(0)])
        self._step = np.concatenate([np.full(p.size, p.step) for p in params] or [np.zeros(0)])
        prior = np.concatenate(
            [np.full(p.size, p.has_prior) for p in params] or [np.zeros(0, bool)]
        )
        self._prior_idx = np.flatnonzero(prior)
        scale = np.concatenate([np.full(p.size, p.scale) for p in params] or [np.zeros(0)])
        # z-units per prior sd: (u - loc)/scale = z * typical/scale.
        self._prior_gain = self._step[self._prior_idx] / scale[self._prior_idx]
        self._log_norm = float(
            -np.sum(np.log(scale[self._prior_idx])) - 0.5 * self._prior_idx.size * _LOG_2PI
        )

    # ----------------------------------------------------------------- introspection
    def __repr__(self) -> str:
        inner = ", ".join(
            f"{p.name}{list(p.shape) if p.shape else ''}:{p.transform}" for p in self.params
        )
        return f"ParamSpace({inner}; size={self.size})"

    def __len__(self) -> int:
        return len(self.params)

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __getitem__(self, name: str) -> Param:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"no parameter {name!r}; known: {list(self.names)}") from None

    @property
    def n_prior(self) -> int:
        """Number of elements with a proper prior (= length of :meth:`prior_residuals`)."""
        return int(self._prior_idx.size)

    @property
    def prior_sd_z(self) -> np.ndarray:
        """The prior's sd in z-units per flat element (``scale/typical``; inf where flat)."""
        out = np.full(self.size, np.inf)
        out[self._prior_idx] = 1.0 / self._prior_gain
        return out

    @property
    def loc(self) -> np.ndarray:
        """Prior mean of ``u`` per flat element."""
        return self._loc.copy()

    @property
    def step(self) -> np.ndarray:
        """``typical`` per flat element: ``u = loc + step * z``."""
        return self._step.copy()

    def flat_names(self) -> list[str]:
        """``"name"`` for scalars, ``"name[i]"``/``"name[i,j]"`` for array elements, in z order."""
        out: list[str] = []
        for p in self.params:
            out.extend(flat_element_names(p.name, p.shape))
        return out

    def flat_indices(self, names: Iterable[str]) -> np.ndarray:
        """Indices into ``z`` of all elements of the named parameters, in the order given."""
        names = [names] if isinstance(names, str) else list(names)
        return np.concatenate(
            [np.arange(self.size)[self.slices[self[n].name]] for n in names] or [np.zeros(0, int)]
        ).astype(int)

    def subset(self, names: Iterable[str]) -> ParamSpace:
        """The space of the named parameters only (in the order given)."""
        names = [names] if isinstance(names, str) else list(names)
        return ParamSpace([self[n] for n in names])

    # ----------------------------------------------------------------- maps
    def to_u(self, z: ArrayLike) -> Array:
        """Unconstrained values, flat: ``u = loc + typical * z``."""
        z = _asarray(z)
        self._check_z(z)
        return self._loc + self._step * z

    def to_values(self, z: ArrayLike) -> dict[str, Array]:
        """Named constrained values: ``z`` (..., size) → ``{name: (..., *shape)}``."""
        u = self.to_u(z)
        xp = _xp(u)
        batch = u.shape[:-1]
        out = {}
        for p in self.params:
            up = u[..., self.slices[p.name]].reshape(batch + p.shape)
            out[p.name] = xp.exp(up) if p.transform == "log" else up
        return out

    def to_z(self, values: Mapping[str, ArrayLike]) -> Array:
        """Inverse of :meth:`to_values` for one point; missing names go to the prior ``loc``."""
        unknown = sorted(set(values) - set(self.names))
        if unknown:
            raise KeyError(f"unknown parameter(s) {unknown}; known: {list(self.names)}")
        xp = jnp if any(isinstance(v, jax.Array) for v in values.values()) else np
        parts = []
        for p in self.params:
            if p.name not in values:
                parts.append(xp.zeros(p.size))
                continue
            v = xp.asarray(values[p.name], dtype=float)
            if v.shape != p.shape:
                try:
                    v = xp.broadcast_to(v, p.shape)
                except ValueError:
                    raise ValueError(
                        f"parameter {p.name!r}: value of shape {v.shape} does not fit {p.shape}"
                    ) from None
            if p.transform == "log":
                if not isinstance(v, jax.core.Tracer) and bool(np.any(np.asarray(v) <= 0)):
                    raise ValueError(
                        f"parameter {p.name!r} is log-transformed: values must be > 0, got {v}"
                    )
                v = xp.log(v)
            parts.append(((v - p.loc) / p.step).reshape(-1))
        return xp.concatenate(parts) if parts else xp.zeros(0)

    def value_derivative(self, z: ArrayLike) -> Array:
        """``d value / d z`` per flat element (diagonal map): ``typical`` or ``typical*exp(u)``."""
        u = self.to_u(z)
        xp = _xp(u)
        parts = []
        for p in self.params:
            sl = self.slices[p.name]
            d = self._step[sl] * (xp.exp(u[..., sl]) if p.transform == "log" else 1.0)
            parts.append(xp.broadcast_to(d, u[..., sl].shape))
        return xp.concatenate(parts, axis=-1) if parts else xp.zeros(u.shape)

    # ----------------------------------------------------------------- prior
    def prior_residuals(self, z: ArrayLike) -> Array:
        """Whitened prior residuals ``(u - loc)/scale`` for every element with finite ``scale``."""
        z = _asarray(z)
        self._check_z(z)
        return z[..., self._prior_idx] * self._prior_gain

    def log_prior(self, z: ArrayLike) -> Array:
        r"""Log prior density over ``u``.

        :math:`-\tfrac12\sum r_i^2 - \sum\log s_i - \tfrac n2\log 2\pi` over the elements with
        a proper prior; flat elements contribute nothing (improper, density 1).
        """
        r = self.prior_residuals(z)
        return -0.5 * _xp(r).sum(r**2, axis=-1) + self._log_norm

    def sample_prior_z(self, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
        """Draws of ``z`` from the prior (flat elements: error, there is nothing to draw)."""
        flat = [p.name for p in self.params if not p.has_prior]
        if flat:
            raise ValueError(f"cannot sample a flat (improper) prior: {flat}")
        shape = (self.size,) if n is None else (n, self.size)
        return rng.standard_normal(shape) / self._prior_gain

    # ----------------------------------------------------------------- helpers
    def flatten(self, values: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
        """``{"b": [1, 2]}`` → ``{"b[0]": 1, "b[1]": 2}`` (leading batch axes kept)."""
        out: dict[str, np.ndarray] = {}
        for p in self.params:
            if p.name not in values:
                continue
            v = np.asarray(values[p.name])
            batch = v.shape[: v.ndim - len(p.shape)]
            flat = v.reshape((*batch, p.size))
            for i, nm in enumerate(flat_element_names(p.name, p.shape)):
                out[nm] = flat[..., i]
        return out

    def _check_z(self, z: Array | np.ndarray) -> None:
        if z.ndim == 0 or z.shape[-1] != self.size:
            raise ValueError(
                f"working vector has shape {z.shape}; this space needs (..., {self.size}) "
                f"for parameters {list(self.names)}"
            )


def _xp(x: object):
    """``jax.numpy`` for JAX arrays and tracers (jit-safe), NumPy otherwise (no dispatch cost)."""
    return jnp if isinstance(x, jax.Array) else np


def _asarray(x: ArrayLike) -> Array | np.ndarray:
    return x if isinstance(x, jax.Array) else np.asarray(x, dtype=float)
