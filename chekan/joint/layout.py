"""A record laid out for the joint model: static structure, array pytree, padding.

- :class:`ModelStructure` — the hashable shape of the problem (holds, bins, slew samples,
  drift and encoder degrees): what decides compilation. β's layout follows from it.
- :class:`RecordData` — the arrays of one record (a frozen dataclass registered as a pytree,
  every field a leaf):
  the ``data`` argument of every model function. :meth:`RecordData.pad` lays it out for
  a larger structure; :meth:`RecordData.with_level` moves the level reference.
- :class:`RecordModel` — structure + data + what the reports need on the host.

Binning (:func:`chekan.joint.binning.prepare_record`) builds them from a record.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from chekan.jaxconfig import device_array, device_arrays
from chekan.joint.angles import AngleSensorSpec
from chekan.joint.xresponse import M0_TOLERANCE_PIX


@dataclass(frozen=True)
class ModelStructure:
    """The static shape of a record model: H holds, N bins, M slew samples per hold,
    drift degree D, encoder degree L (legacy smooth angle error), S systematic
    angle-error terms (per angle sensor: one per commanded angle, plus the scale error)
    and X terms per system for the X rounds' response beyond eq. (6) (0 for records
    without rounds about X; :mod:`chekan.joint.xresponse`). Hashable; equal structures
    share compiled code."""

    n_holds: int
    n_bins: int
    n_moves: int
    drift_degree: int = 3
    encoder_degree: int = 0
    n_systematic: int = 0
    n_x_response: int = 0

    @property
    def beta_blocks(self) -> dict[str, np.ndarray]:
        """β's layout: (c₁, d₁, ν₁, c₂, d₂, ν₂, o₁, o₂, δ, e, ζ) as index arrays per block."""
        return beta_blocks(
            self.n_holds,
            self.drift_degree,
            self.encoder_degree,
            self.n_systematic,
            self.n_x_response,
        )

    @property
    def hold_bands(self) -> np.ndarray:
        """(H, 3) β indices of each hold's (o₁ₖ, o₂ₖ, δₖ): the normal equations couple them
        only with the same and the neighbouring holds (a bin's lag mixes its own hold and the
        one before), so in this order they form a block-tridiagonal part
        (:func:`inference.normal_eq.banded_factor`)."""
        b = self.beta_blocks
        H = self.n_holds
        return np.stack([b["hold_offset"][:H], b["hold_offset"][H:], b["angle_error"]], axis=1)

    @property
    def n_q(self) -> int:
        """Columns per system that do not go through the holds: cⱼ, dⱼ, νⱼ."""
        return 1 + self.drift_degree + self.n_x_response

    @property
    def n_angle_cols(self) -> int:
        """Columns of the shared angle-error basis: encoder (L) then systematic (S)."""
        return self.encoder_degree + self.n_systematic

    @property
    def n_beta(self) -> int:
        """Number of linear (marginalised) parameters."""
        return int(sum(len(ix) for ix in self.beta_blocks.values()))

    def beta_index(self, j: int) -> np.ndarray:
        """Global β indices of system j's local columns [cⱼ, dⱼ, νⱼ, oⱼ, δ, e]."""
        b, q, H = self.beta_blocks, self.n_q, self.n_holds
        return np.concatenate(
            [
                j * q + np.arange(q),
                b["hold_offset"][j * H : (j + 1) * H],
                b["angle_error"],
                b["encoder"],
                b["angle_systematic"],
            ]
        )


def beta_blocks(H: int, D: int, L: int, S: int = 0, X: int = 0) -> dict[str, np.ndarray]:
    """β's layout: (c₁, d₁, ν₁, c₂, d₂, ν₂, o₁, o₂, δ, e, ζ): level offsets, drift and the
    X-response terms per system, hold offsets, the random angle error of every hold, the
    legacy encoder terms and the systematic angle-error terms shared by all rounds."""
    q = 1 + D + X  # per system: level offset cⱼ, drift dⱼ, X response νⱼ
    o0, a0, e0 = 2 * q, 2 * q + 2 * H, 2 * q + 3 * H
    return {
        "c": np.array([0, q]),
        "drift": np.concatenate([np.arange(1, 1 + D), q + np.arange(1, 1 + D)]),
        "x_response": np.concatenate([1 + D + np.arange(X), q + 1 + D + np.arange(X)]),
        "hold_offset": np.arange(o0, o0 + 2 * H),  # system 1's holds, then system 2's
        "angle_error": np.arange(a0, a0 + H),
        "encoder": np.arange(e0, e0 + L),
        "angle_systematic": np.arange(e0 + L, e0 + L + S),
    }


def _padded(axes: str, fill: float | bool) -> Any:
    """A data field padded along ``axes`` (H holds, N bins, M slew samples, Q shared
    columns, X X-response terms) with ``fill`` (a ``dataclasses.field``)."""
    return dataclasses.field(metadata={"pad": (axes, fill)})


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class RecordData:
    """The arrays of one record for the joint model (units in the names or below)."""

    g: jax.Array  # mGal, local gravity
    m0: jax.Array  # pix, CCD centre
    m_ref: jax.Array  # (2,) pix, level reference reading of each system
    dt: jax.Array  # s, sample period
    sigma_base: jax.Array  # (2,) pix, per-sample noise from first differences
    x_prior_var: jax.Array = _padded("X", 1.0)  # (X,) pix², prior variances of the X terms νⱼ
    hold_tx: jax.Array = _padded("H", 0.0)  # (H,) rad, reported attitude of each hold
    hold_ty: jax.Array = _padded("H", 0.0)
    hold_T: jax.Array = _padded("H", 0.0)  # (H,) s, slew end to hold end
    hold_dir: jax.Array = _padded("H", 0.0)  # (H, 2) unit vector of the hold's tilt (x, y)
    mv_dir: jax.Array = _padded("H", 0.0)  # (H, 2) unit vector of the slew into each hold
    x_basis: jax.Array = _padded("HX", 0.0)  # (H, X) pix, X-response columns at the holds
    hold_mask: jax.Array = _padded("H", False)  # (H,) real holds
    angle_basis: jax.Array = _padded("HQ", 0.0)  # (H, Q) shared angle-error terms, arcsec
    angle_prior_var: jax.Array = _padded("Q", 1.0)  # (Q,) arcsec², their prior variances
    own: jax.Array = _padded("NH", 0.0)  # (N, H) bin i lies in hold k
    prev: jax.Array = _padded("NH", 0.0)  # (N, H) hold before bin i's hold
    bin_hold: jax.Array = _padded("N", 0)  # (N,) int, bin i's hold (padding: 0, no weight)
    d0: jax.Array = _padded("N", 1e9)  # (N,) s, slew end to the bin's first sample
    dstep: jax.Array = _padded("N", 1.0)  # (N,) s, sample spacing in the bin
    n_t: jax.Array = _padded("N", 1.0)  # (N,) samples in the bin
    y: jax.Array = _padded("N", 0.0)  # (N, 2) pix, bin means
    cnt: jax.Array = _padded("N", 0.0)  # (N, 2) finite samples per bin mean
    mask: jax.Array = _padded("N", False)  # (N, 2) bins with data
    drift_basis: jax.Array = _padded("N", 0.0)  # (N, D) Legendre in scaled time, no constant
    mv_tx: jax.Array = _padded("HM", 0.0)  # (H, M) rad, slew samples into each hold
    mv_ty: jax.Array = _padded("HM", 0.0)
    mv_lag: jax.Array = _padded("HM", 0.0)  # (H, M) s, t_last − tᵢ
    mv_mask: jax.Array = _padded("HM", False)
    mv_angle_basis: jax.Array = _padded("HMQ", 0.0)  # (H, M, Q) shared terms along slews
    mv_x_basis: jax.Array = _padded("HMX", 0.0)  # (H, M, X) pix, X-response terms along slews
    # (n_β,) int, padded records only: which standard normal of a draw of β each of its
    # entries takes (:func:`beta_noise_order`); None: the i-th
    noise_order: jax.Array | None = None

    def pad(self, H: int, N: int, M: int, Q: int | None = None, X: int | None = None) -> RecordData:
        """The same record laid out for H holds, N bins, M slew samples, Q shared
        angle-error columns and X X-response terms per system (None: as it is).

        Exact: padded bins have ``mask`` False (zero weight), padded holds have no bins
        (``own``/``prev`` columns zero, so their β is its prior mean 0 and adds nothing to
        the residuals) and sit after the real ones (the unsettled-carry scan runs
        forwards), padded slew samples have ``mv_mask`` False, padded angle-error
        columns are zero (their β stays at its prior mean 0). Padded X-response columns
        are zero with unit prior variance (nothing in the quadratic form, and log 1 = 0 in
        both log-determinants) and go before the last one, the level angle Δm₀ⱼ that the
        derived quantities read (:func:`chekan.joint.derived.physical_quantities`).
        """
        h0, n0, m0 = self.hold_tx.shape[0], self.y.shape[0], self.mv_tx.shape[1]
        q0, x0 = self.angle_basis.shape[1], self.x_prior_var.shape[0]
        Q = q0 if Q is None else Q
        X = x0 if X is None else X
        if H < h0 or N < n0 or M < m0 or Q < q0 or X < x0 or (X > x0 == 0):
            raise ValueError(
                f"cannot pad ({h0}, {n0}, {m0}, {q0}, {x0}) to ({H}, {N}, {M}, {Q}, {X})"
            )
        extra = {"H": H - h0, "N": N - n0, "M": M - m0, "Q": Q - q0, "X": X - x0}
        # the X axis: zeros appended, then moved before the last (level angle) column
        x_order = np.r_[np.arange(x0 - 1), np.arange(x0, X), x0 - 1] if x0 else np.arange(0)
        changes: dict[str, Any] = {"noise_order": None}  # set by RecordModel.pad
        for f in dataclasses.fields(self):
            if "pad" not in f.metadata:
                continue
            axes, fill = f.metadata["pad"]
            x = np.asarray(getattr(self, f.name))
            widths = [(0, extra[a]) for a in axes] + [(0, 0)] * (x.ndim - len(axes))
            x = np.pad(x, widths, constant_values=fill)
            if "X" in axes and X > x0:
                x = np.take(x, x_order, axis=axes.index("X"))
            changes[f.name] = x
        return dataclasses.replace(self, **device_arrays(changes))

    def with_noise_order(self, order: np.ndarray) -> RecordData:
        """The same data whose draws of β take their normals in ``order``."""
        return dataclasses.replace(self, noise_order=device_array(order, dtype=np.int32))

    def with_level(self, m_ref: Any) -> RecordData:
        """The same data with the level reference reading moved to ``m_ref`` (pix)."""
        return dataclasses.replace(self, m_ref=device_array(m_ref, dtype=np.float64))


@dataclass(frozen=True)
class RecordModel:
    """One record for the joint model: structure, arrays, and host-side labels."""

    structure: ModelStructure
    data: RecordData
    hold_steps: np.ndarray  # program step of each real hold
    bin_t_s: np.ndarray  # s, mid-time of each real bin
    t_span_s: tuple[float, float]  # s, first and last sample
    angle_spec: AngleSensorSpec | None = None  # the Y sensor's systematic error prior, if modelled
    angle_spec_x: AngleSensorSpec | None = None  # the X sensor's, where the record tilts about X
    n_systematic_x: int = 0  # the X sensor's systematic terms (after the common one)
    horizontal_u_pix: float = M0_TOLERANCE_PIX  # the pendulums' horizontal about the centre

    @property
    def n_systematic_common(self) -> int:
        """The scale error both sensors may share: one term, the block's first, where both
        read holds (:func:`chekan.joint.angles.all_sensor_terms`)."""
        return int(self.angle_spec is not None and self.angle_spec_x is not None)

    @property
    def n_holds(self) -> int:
        return self.structure.n_holds

    @property
    def n_bins(self) -> int:
        return self.structure.n_bins

    @property
    def drift_degree(self) -> int:
        return self.structure.drift_degree

    @property
    def encoder_degree(self) -> int:
        return self.structure.encoder_degree

    @property
    def beta_blocks(self) -> dict[str, np.ndarray]:
        return self.structure.beta_blocks

    @property
    def n_beta(self) -> int:
        return self.structure.n_beta

    @property
    def duration_h(self) -> float:
        return (self.t_span_s[1] - self.t_span_s[0]) / 3600.0

    def pad(
        self, H: int, N: int, M: int, S: int | None = None, X: int | None = None
    ) -> RecordModel:
        """This record laid out for a larger structure (:meth:`RecordData.pad`); S is the
        number of systematic angle-error terms, X of X-response terms per system (None: as
        it is). The host-side labels (``hold_steps``, ``bin_t_s``) stay the real ones; the
        data always carries its ``noise_order`` (one argument tree for a bucket)."""
        s = self.structure
        S = s.n_systematic if S is None else S
        X = s.n_x_response if X is None else X
        if (H, N, M, S, X) == (s.n_holds, s.n_bins, s.n_moves, s.n_systematic, s.n_x_response):
            if self.data.noise_order is not None:
                return self
            # a record that fills its bucket: the same data tree as the bucket's others
            order = beta_noise_order(s, s)
            return dataclasses.replace(self, data=self.data.with_noise_order(order))
        if S < s.n_systematic:
            raise ValueError(f"cannot pad {s.n_systematic} systematic terms down to {S}")
        new = dataclasses.replace(s, n_holds=H, n_bins=N, n_moves=M, n_systematic=S, n_x_response=X)
        data = self.data.pad(H, N, M, new.n_angle_cols, X)  # checks the sizes first
        data = data.with_noise_order(beta_noise_order(s, new, self.data.noise_order))
        return dataclasses.replace(self, structure=new, data=data)

    @property
    def n_real_holds(self) -> int:
        """Holds of the record itself (the first ones; the rest is padding)."""
        return len(self.hold_steps)

    @property
    def n_real_bins(self) -> int:
        """Bins of the record itself (the first ones; the rest is padding)."""
        return len(self.bin_t_s)

    def with_level(self, m_ref: Any) -> RecordModel:
        """This record with the level reference reading moved to ``m_ref`` (pix)."""
        return dataclasses.replace(self, data=self.data.with_level(m_ref))


def padded_beta_index(real: ModelStructure, padded: ModelStructure) -> np.ndarray:
    """(n_β of ``real``,) the index in ``padded``'s β of each of ``real``'s β entries
    (:meth:`RecordModel.pad`: holds and systematic terms appended, the X-response terms
    inserted before each system's last one)."""
    b0, b1 = real.beta_blocks, padded.beta_blocks
    out = np.zeros(real.n_beta, dtype=int)
    H0, H1, X0, X1 = real.n_holds, padded.n_holds, real.n_x_response, padded.n_x_response
    for name, ix in b0.items():
        if name == "hold_offset":  # system 1's holds, then system 2's
            out[ix] = np.r_[b1[name][:H0], b1[name][H1 : H1 + H0]]
        elif name == "x_response" and X0:  # per system: all but the last, …, the last
            cols = np.r_[np.arange(X0 - 1), X1 - 1]
            out[ix] = np.r_[b1[name][cols], b1[name][X1 + cols]]
        else:
            out[ix] = b1[name][: len(ix)]
    return out


def draw_order(structure: ModelStructure) -> np.ndarray:
    """β's indices in the order a draw of β takes its normals: the holds' (o₁ₖ, o₂ₖ, δₖ)
    band by band, then the other entries ascending
    (:func:`inference.normal_eq.draw_beta_blocks`)."""
    bands = structure.hold_bands.reshape(-1)
    return np.r_[bands, np.setdiff1d(np.arange(structure.n_beta), bands)]


def beta_noise_order(
    real: ModelStructure, padded: ModelStructure, before: Any = None
) -> np.ndarray:
    """(n_β of ``padded``,) which standard normal each entry of a draw of β takes, so that
    a padded record's real entries take the normals they take unpadded (padding is exact
    for ``bayes`` too, draw by draw): a draw's normals are ``jax.random.normal(key, n_β)``
    and the i-th does not depend on n_β (JAX's partitionable threefry), so the real
    entries keep their positions' numbers and the padding's take those after.
    ``before``: the order of a record padded already (None: its own)."""
    n0 = real.n_beta
    prev = np.arange(n0) if before is None else np.asarray(before)
    u0 = np.empty(n0, dtype=int)
    u0[draw_order(real)] = np.arange(n0)  # position of each real β in its draw
    u1 = np.empty(padded.n_beta, dtype=int)
    u1[draw_order(padded)] = np.arange(padded.n_beta)
    order = np.full(padded.n_beta, -1)
    order[u1[padded_beta_index(real, padded)]] = prev[u0]
    pad = order < 0
    order[pad] = n0 + np.arange(int(pad.sum()))
    return order
