"""MAP of many datasets of one problem at once: :func:`fit_map_batch` (``jax.vmap`` over
the lanes, optionally in groups), :class:`MapBatchResult`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from .laplace import DEFAULT_RCOND, LaplaceCovariance
from .map import (
    _SUCCESS,
    MapResult,
    SolverName,
    _compiled,
    _host_values,
    _laplace,
    _laplace_names,
    _messages,
    _value_sd,
    _z0,
)
from .params import ParamSpace
from .problem import LeastSquaresProblem

__all__ = ["MapBatchResult", "fit_map_batch"]


@dataclass
class MapBatchResult:
    """Per-lane MAP estimates of :func:`fit_map_batch`; arrays have a leading batch axis B."""

    z: np.ndarray  # (B, p)
    values: dict[str, np.ndarray]  # (B, *shape)
    converged: np.ndarray  # (B,) bool
    num_steps: np.ndarray  # (B,) int
    result_codes: np.ndarray  # (B,) int: optimistix's result codes (0: success)
    cost: np.ndarray  # (B,)
    cov_z: np.ndarray  # (B, p, p)
    sd: dict[str, np.ndarray]  # (B, *shape) Laplace sd in value space
    jacobian_cond: np.ndarray  # (B,)
    degenerate: list[list[str]]
    residuals: np.ndarray  # (B, n) stacked whitened residuals at the MAP
    space: ParamSpace = field(repr=False)
    jacobian: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)), repr=False)
    _laplace: list[LaplaceCovariance] = field(default_factory=list, repr=False)

    def __len__(self) -> int:
        return self.z.shape[0]

    @property
    def messages(self) -> list[str]:
        """One message per lane (:attr:`MapResult.message`)."""
        return _messages(self.result_codes)

    def item(self, i: int) -> MapResult:
        """Lane ``i`` as a :class:`MapResult`."""
        return MapResult(
            z=self.z[i],
            values={k: v[i] for k, v in self.values.items()},
            converged=bool(self.converged[i]),
            num_steps=int(self.num_steps[i]),
            result_code=int(self.result_codes[i]),
            cost=float(self.cost[i]),
            cov_z=self.cov_z[i],
            jacobian_cond=float(self.jacobian_cond[i]),
            degenerate=list(self.degenerate[i]),
            degenerate_directions=self._laplace[i].degenerate_directions,
            residuals=self.residuals[i],
            space=self.space,
            jacobian=self.jacobian[i] if len(self.jacobian) else np.zeros((0, 0)),
        )


def _batch_size(data_batch: Any, data_axes: Any, z0_batch: Any) -> int:
    """Size of the vmapped axis, checked to agree across the batched leaves and z0_batch."""
    sizes: list[int] = []

    def visit(ax, sub):
        if ax is not None:
            sizes.extend(int(np.shape(leaf)[ax]) for leaf in jax.tree_util.tree_leaves(sub))

    jax.tree_util.tree_map(visit, data_axes, data_batch, is_leaf=lambda x: x is None)
    if z0_batch is not None and not isinstance(z0_batch, Mapping):
        sizes.append(int(np.shape(z0_batch)[0]))
    if not sizes:
        raise ValueError("data_batch has no batched leaf (data_axes all None): nothing to vmap")
    if len(set(sizes)) != 1:
        raise ValueError(f"batched leaves disagree on the batch size: {sorted(set(sizes))}")
    return sizes[0]


def _in_groups(run, z0, data_batch, data_axes, batch: int, lanes: int):
    """``run`` over groups of ``lanes`` lanes, outputs concatenated back to ``batch``."""

    def take(ix):
        def pick(ax, sub):
            if ax is None:
                return sub
            return jax.tree_util.tree_map(lambda leaf: jnp.take(leaf, ix, axis=ax), sub)

        return pick

    outs = []
    for start in range(0, batch, lanes):
        ix = jnp.asarray(np.minimum(np.arange(start, start + lanes), batch - 1))
        # data_axes is a prefix of data_batch (an int alone covers the whole tree)
        d = jax.tree_util.tree_map(take(ix), data_axes, data_batch, is_leaf=lambda x: x is None)
        outs.append(run(z0[ix], d))
    n_real = [min(lanes, batch - start) for start in range(0, batch, lanes)]

    def join(*parts):
        return jnp.concatenate([x[:n] for x, n in zip(parts, n_real, strict=True)])

    # pytrees (optimistix's RESULTS is one), joined leaf by leaf
    return tuple(jax.tree_util.tree_map(join, *[o[k] for o in outs]) for k in range(len(outs[0])))


def fit_map_batch(
    problem: LeastSquaresProblem,
    data_batch: Any,
    z0_batch: ArrayLike | None = None,
    *,
    data_axes: Any = 0,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    max_steps: int = 256,
    solver: SolverName = "lm",
    rcond: float = DEFAULT_RCOND,
    max_lanes: int | None = None,
    sd_tol: float | None = None,
) -> MapBatchResult:
    """MAP for B datasets at once (``jax.vmap`` over the leading axis of ``data_batch``).

    All lanes must have the same shapes: pad and mask in the residual function (padded
    residuals exactly 0). ``data_axes`` is the vmap ``in_axes`` prefix for the data: use
    ``None`` for leaves shared by all lanes, e.g. ``{"t": None, "y": 0}``. ``z0_batch``: (B, p)
    or None (prior loc). Compiled once per problem and data shapes.

    ``max_lanes``: solve in vmapped groups of at most this many lanes (the last group padded
    by repeating its last lane, so one compile serves all groups). On the XLA CPU runtime
    of jax 0.10 a vmapped solve of a large model over 4 or more lanes can deadlock in the
    intra-op thread pool (all threads idle, never returns); groups of 2 do not.
    ``sd_tol``: as in :func:`fit_map`.
    """
    space = problem.space
    batch = _batch_size(data_batch, data_axes, z0_batch)
    run = _compiled(
        problem, solver, rtol, atol, max_steps, batched=True, data_axes=data_axes, sd_tol=sd_tol
    )
    z0 = _z0(space, z0_batch, batch)
    if max_lanes is None or max_lanes >= batch:
        out = run(z0, data_batch)
    else:
        out = _in_groups(run, z0, data_batch, data_axes, batch, max_lanes)
    # every output to the host in one transfer, as in fit_map
    z, result, steps, r, s, vt, jac = jax.device_get(out)
    laps = [_laplace(s[i], vt[i], r[i], rcond) for i in range(batch)]
    cov_z = np.stack([lap.cov for lap in laps]) if batch else np.zeros((0, space.size, space.size))
    sds = [_value_sd(space, z[i], cov_z[i]) for i in range(batch)]
    return MapBatchResult(
        z=z,
        values=_host_values(space, z),
        converged=result == _SUCCESS,
        num_steps=steps,
        result_codes=result.reshape(-1),
        cost=0.5 * np.sum(r**2, axis=1),
        cov_z=cov_z,
        sd={p.name: np.stack([d[p.name] for d in sds]) for p in space.params},
        jacobian_cond=np.array([lap.cond for lap in laps]),
        degenerate=[_laplace_names(space, lap) for lap in laps],
        residuals=r,
        space=space,
        jacobian=jac,
        _laplace=laps,
    )
