r"""The entries of the inverse of block normal equations on their own sparsity pattern.

For the arrow structure of :class:`inference.normal_eq.BlockNormalEquations` (banded blocks
B coupled to a few dense variables D), the variances of β and the leverages of rows that
touch two neighbouring blocks and the dense variables need only the blocks of
:math:`Z = M^{-1}` where M has entries: the selected inverse (Takahashi's recursion on the
factor of :func:`inference.normal_eq.banded_factor_blocks`), O(H k³ + H k m²) instead of
the dense O((Hk + m)³).
"""

from __future__ import annotations

from . import _jax  # noqa: F401  (float64 before any array exists)

# isort: split

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jax import Array

from .normal_eq import BandedFactor, _small_forward

__all__ = ["SelectedInverse", "selected_inverse"]


class SelectedInverse(NamedTuple):
    """The entries of Z = M⁻¹ on the sparsity pattern of M for the arrow structure of
    :class:`BlockNormalEquations` (:func:`selected_inverse`): what the variances of β and the
    leverages of rows that touch two neighbouring blocks and the dense variables need."""

    diag: Array  # (H, k, k) Z_ii
    sub: Array  # (H, k, k) Z_{i,i−1} (block 0: zeros)
    cross: Array  # (H, k, m) Z_{B_i, D}
    dense: Array  # (m, m) Z_DD


def selected_inverse(f: BandedFactor, unroll: int = 4) -> SelectedInverse:
    r"""The blocks of :math:`Z = M^{-1}` where M has entries (:class:`SelectedInverse`), from
    the factor of :func:`banded_factor_blocks`, in O(H k³ + H k m²) instead of the dense
    O((Hk + m)³).

    With :math:`W = B^{-1}C = L_B^{-\top}Y` and :math:`S^{-1} = L_S^{-\top}L_S^{-1}`:
    :math:`Z_{DD} = S^{-1}`, :math:`Z_{BD} = -WS^{-1}`,
    :math:`Z_{BB} = B^{-1} + WS^{-1}W^\top`; the blocks of :math:`B^{-1}` on the band by the
    backward recursion of :math:`L_B^\top B^{-1} = L_B^{-1}` (Takahashi):
    :math:`B^{-1}_{i,i+1} = -L_{ii}^{-\top}L_{i+1,i}^\top B^{-1}_{i+1,i+1}`,
    :math:`B^{-1}_{ii} = L_{ii}^{-\top}(L_{ii}^{-1} - L_{i+1,i}^\top B^{-1}_{i+1,i})`.
    """
    H, k = f.diag.shape[:2]
    m = f.L_S.shape[0]
    eye_k = jnp.eye(k)
    inv_ii = jax.vmap(lambda L: _small_forward(L, eye_k))(f.diag)  # L_ii⁻¹
    sub_next = jnp.concatenate([f.sub[1:], jnp.zeros((1, k, k))])  # L_{i+1,i}
    Yb = f.Y.reshape(H, k, m)

    def step(carry, blocks):
        Z_next, W_next = carry  # B⁻¹_{i+1,i+1}, W_{i+1}
        Li, Lni, Y_i = blocks
        X = -Li.T @ (Lni.T @ Z_next)  # B⁻¹_{i,i+1}
        Z_ii = Li.T @ (Li - Lni.T @ X.T)
        W_i = Li.T @ (Y_i - Lni.T @ W_next)
        return (Z_ii, W_i), (Z_ii, X, W_i)

    first = (jnp.zeros((k, k)), jnp.zeros((k, m)))
    _, (Bd, X, W) = jax.lax.scan(step, first, (inv_ii, sub_next, Yb), reverse=True, unroll=unroll)
    inv_S = jsl.solve_triangular(f.L_S, jnp.eye(m), lower=True)
    Z_DD = inv_S.T @ inv_S
    P = W @ Z_DD  # (H, k, m) W S⁻¹ = −Z_BD
    W_prev = jnp.concatenate([jnp.zeros((1, k, m)), W[:-1]])
    X_prev = jnp.concatenate([jnp.zeros((1, k, k)), X[:-1]])  # B⁻¹_{i−1,i}
    diag = Bd + jnp.einsum("hkm,hlm->hkl", P, W)
    sub = jnp.swapaxes(X_prev, 1, 2) + jnp.einsum("hkm,hlm->hkl", P, W_prev)
    sub = sub.at[0].set(0.0)
    return SelectedInverse(diag, sub, -P, Z_DD)
