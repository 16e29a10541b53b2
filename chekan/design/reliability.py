r"""The expected reliability of a program's uncertainty: ν_eff and k before the record exists.

A certificate states U = k·u with k = t₉₅.₄₅(ν_eff) (GUM G.4.1, G.6.4), where ν_eff says how
well the record determines the variance components that u rests on (the noise scales s₁,
s₂, the slew error κ, the holds' random angle error σ_θ and offset σ_o:
:mod:`chekan.fit.typea`, :mod:`inference.dof`). A program can have a small expected sd
and still leave those components undetermined: two angles held once each (six holds)
give every hold its own systematic term, and nothing is left to tell a hold's random
error from it. Its certificate then carries a large k, or none (ν_eff < 1).

Here the estimator's reading is applied to the design's linear model
(:func:`chekan.design.information.design_rows`) at the design values. The whitened
stacked rows are K = [W^{1/2} [X, L]; Λ^{-1/2}], Σ = (KᵀK)⁻¹ and the hat matrix
H = K Σ Kᵀ; a quantity q with gradient ∇q has the row influences h = ∇q Σ Kᵀ
(u² = Σ hᵣ² = ∇q Σ ∇qᵀ, the expected sd's square), and with the shares Dₐᵣ of each
component in each row's variance:

.. math::

    I = ½ D (P∘P) Dᵀ + I_{prior},\quad V = I^{-1},\quad g = D h^{∘2},\quad
    E[u_h^2] = \mathrm{tr}\,V\,(D∘h) P (D∘h)ᵀ,\quad
    ν_{eff} = 2\,(u^2 + E[u_h^2])^2 / gᵀ V g,

P = I − H the residuals' covariance (E[rrᵀ] for whitened rows), I_prior the priors on
log s and log κ that the EM uses (:data:`chekan.fit.typea.PRIOR_INFO`). The Type B
terms (systematic angle errors) are rows with a fixed prior: they add to u² and nothing to
its uncertainty, as a line with ν = ∞ in the Welch–Satterthwaite sum.

The cost is dense algebra on ≈ 2N + n_g + 3H rows (≈ 0.1–1 s for a 9 h program): a search
evaluates it only for the programs it shows and the one it picks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from chekan.design.information import THETA_NAMES, DesignRows, design_rows
from chekan.design.layout import DesignValues
from chekan.fit.typea import COMPONENTS, PRIOR_INFO
from chekan.physics.program import TiltProgram
from inference.dof import (
    component_information,
    cov_of_information,
    coverage_factor,
    welch_satterthwaite,
)

#: the quantities whose ν_eff a design reports
QUANTITIES = ("b1", "b2", "a", "b1_0", "b2_0")


@dataclass(frozen=True)
class ExpectedReliability:
    """ν_eff and k of each quantity (:data:`QUANTITIES`) at the design values; ``clipped``:
    the components' information was indefinite (its positive part was inverted)."""

    nu_eff: dict[str, float]
    k: dict[str, float]
    components: tuple[str, ...]
    clipped: bool

    def nu_of(self, objective: str) -> float:
        """The smallest ν_eff of the quantities an objective (b_mean, b_max, a) rests on."""
        names = ("a",) if objective == "a" else ("b1", "b2")
        return min(self.nu_eff[n] for n in names)

    def k_of(self, objective: str) -> float:
        """k for :meth:`nu_of` (inf below one degree of freedom)."""
        return coverage_factor(self.nu_of(objective))


def _stacked(rows: DesignRows) -> tuple[np.ndarray, np.ndarray]:
    """K (2N + n_g + n_b, n_g + n_b), and each row's shares D (5, rows) of the
    components :data:`chekan.fit.typea.COMPONENTS`."""
    N = rows.base.shape[0]
    ng, nb = rows.prec_g.size, rows.prec_b.size
    n_par = ng + nb
    K = np.zeros((2 * N + n_par, n_par))
    D = np.zeros((len(COMPONENTS), K.shape[0]))
    var = rows.var
    bins = np.arange(N)[:, None]
    for j in range(2):
        block = np.zeros((N, n_par))
        block[:, :ng] = rows.X[j]
        np.add.at(block, (bins, ng + rows.local_idx[j]), rows.local_val[j])  # duplicates summed
        K[j * N : (j + 1) * N] = block / np.sqrt(var[:, j])[:, None]
        D[j, j * N : (j + 1) * N] = rows.base[:, j] / var[:, j]
        D[2, j * N : (j + 1) * N] = rows.trans2[:, j] / var[:, j]
    prior = 2 * N + np.arange(n_par)
    K[prior, np.arange(n_par)] = np.sqrt(np.concatenate([rows.prec_g, rows.prec_b]))
    # the hold unknowns some bin touches (a random effect switched off touches none)
    real = np.zeros(nb, dtype=bool)
    for j in range(2):
        real[rows.local_idx[j][rows.local_val[j] != 0.0]] = True
    kind = np.arange(nb) % 3  # (o₁, o₂, δ) per hold
    D[3, 2 * N + ng + np.flatnonzero(real & (kind == 2))] = 1.0
    D[4, 2 * N + ng + np.flatnonzero(real & (kind < 2))] = 1.0
    return K, D


def _gradients(rows: DesignRows) -> dict[str, np.ndarray]:
    """∇q over (g, b) of each quantity: b₁, b₂ are θ's first two; a, b₁,₀, b₂,₀ from the
    design values' derivatives over (θ, c, Δm₀), as ``expected_precision`` takes them."""
    n_par = rows.prec_g.size + rows.prec_b.size
    out = {}
    for i, name in enumerate(THETA_NAMES[:2]):
        g = np.zeros(n_par)
        g[i] = 1.0
        out[name] = g
    dg = rows.sens.derived_grad
    for i, name in enumerate(("a", "b1_0", "b2_0")):
        g = np.zeros(n_par)
        g[:6] = dg[i, :6]
        g[7:9] = dg[i, 6:8]
        g[rows.level_cols] = dg[i, 8 : 8 + rows.level_cols.size]
        out[name] = g
    return out


def expected_reliability(
    program: TiltProgram, values: DesignValues | None = None
) -> ExpectedReliability:
    """ν_eff and k of b₁, b₂, a, b₁,₀, b₂,₀ that a record of ``program`` is expected to
    give (module docstring)."""
    rows = design_rows(program, values)
    K, D = _stacked(rows)
    keep = np.any(D != 0.0, axis=1)  # components the program has (switched-off ones: none)
    D, prior_info = D[keep], PRIOR_INFO[np.ix_(keep, keep)]
    Sigma = np.linalg.inv(K.T @ K)
    KS = K @ Sigma
    used = np.any(D != 0.0, axis=0)  # rows no component touches drop out of the traces
    hat = KS[used] @ K[used].T
    P = np.eye(hat.shape[0]) - hat
    Du = D[:, used]
    V, clipped = cov_of_information(component_information(hat, Du) + prior_info)
    nu, k = {}, {}
    for name, grad in _gradients(rows).items():
        h = KS @ grad  # the rows' influences
        u2 = float(grad @ Sigma @ grad)
        g = D @ h**2
        Dh = Du * h[used]
        uh2 = float(np.sum(V * (Dh @ P @ Dh.T)))
        nu[name] = welch_satterthwaite(u2 + max(uh2, 0.0), float(g @ V @ g))
        k[name] = coverage_factor(nu[name])
    names = tuple(c for c, on in zip(COMPONENTS, keep, strict=True) if on)
    return ExpectedReliability(nu, k, names, clipped)
