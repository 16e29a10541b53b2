"""Where an ensemble's walkers start, and how a batch of points is evaluated: a start
ball N(z₀, C) with C regularised (symmetric, eigenvalues ≥ 10⁻⁸·max), or draws of a fitted
proposal, redrawn where the log density is not finite; evaluations only in the compiled
batch size (half the walkers)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .chunks import map_chunks

__all__ = [
    "eval_any",
    "eval_halves",
    "flatten_walkers",
    "initial_walkers",
    "proposal_walkers",
    "regularised_cov",
]


def regularised_cov(init_cov: ArrayLike, ndim: int) -> np.ndarray:
    """A usable covariance for the initial ball: symmetric, finite, eigenvalues ≥ 1e-8·max."""
    c = np.array(init_cov, dtype=float)
    if c.ndim == 0:
        c = np.eye(ndim) * c
    elif c.ndim == 1:
        c = np.diag(c)
    if c.shape != (ndim, ndim):
        raise ValueError(f"init_cov has shape {c.shape}, expected ({ndim}, {ndim})")
    bad = ~np.isfinite(np.diag(c)) | (np.diag(c) <= 0)
    c[bad, :] = 0.0
    c[:, bad] = 0.0
    c[bad, bad] = 1.0  # unidentified / unknown: the O(1) size of a z coordinate
    c[~np.isfinite(c)] = 0.0
    c = 0.5 * (c + c.T)
    w, v = np.linalg.eigh(c)
    top = max(float(w.max()), 1e-300)
    w = np.clip(w, 1e-8 * top, None)
    return (v * w) @ v.T


def initial_walkers(
    lnp: Callable, z_init: np.ndarray, cov: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` walkers from N(z_init, cov) with finite log density (redrawn, shrinking if needed)."""
    chol = np.linalg.cholesky(cov)
    coords = z_init + rng.standard_normal((n, z_init.size)) @ chol.T
    lp = eval_halves(lnp, coords)
    shrink = 1.0
    for attempt in range(60):
        bad = ~np.isfinite(lp)
        if not bad.any():
            return coords, lp
        if attempt >= 10:
            shrink *= 0.7
        coords[bad] = z_init + shrink * rng.standard_normal((bad.sum(), z_init.size)) @ chol.T
        lp[bad] = eval_any(lnp, coords[bad], n // 2)
    raise RuntimeError(
        f"could not place {int(bad.sum())} of {n} initial walkers where the log density is "
        "finite, even in a ball shrunk 60-fold around z_init: check the support of the "
        "log-density (constraints, NaNs) near z_init"
    )


def proposal_walkers(
    lnp: Callable, proposal: Any, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` walkers drawn from the fitted proposal, redrawn where the density is not finite."""
    coords = proposal.sample(n, rng)
    lp = eval_halves(lnp, coords)
    for _ in range(60):
        bad = ~np.isfinite(lp)
        if not bad.any():
            return coords, lp
        coords[bad] = proposal.sample(int(bad.sum()), rng)
        lp[bad] = eval_any(lnp, coords[bad], n // 2)
    raise RuntimeError("could not place the walkers where the log density is finite")


def eval_halves(lnp: Callable, coords: np.ndarray) -> np.ndarray:
    """Evaluate in batches of n/2 so that only emcee's batch size is ever compiled."""
    h = coords.shape[0] // 2
    return np.concatenate([lnp(coords[:h]), lnp(coords[h:])])


def eval_any(lnp: Callable, coords: np.ndarray, batch: int) -> np.ndarray:
    """Evaluate any number of points in batches of ``batch`` (the compiled size, no new
    compiles), several batches on one thread per core (:func:`inference.chunks.map_chunks`):
    the mode's finite differences and the proposal's importance draws are hundreds of
    points, the sampler's steps one batch (in the calling thread)."""
    return map_chunks(lnp, [coords], batch)


def flatten_walkers(x: np.ndarray) -> np.ndarray:
    """(step, walker, ...) → (walker·step, ...), walker-major."""
    x = np.swapaxes(x, 0, 1)
    return x.reshape((x.shape[0] * x.shape[1], *x.shape[2:]))
