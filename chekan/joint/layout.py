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
    columns) with ``fill`` (a ``dataclasses.field``)."""
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
    x_prior_var: jax.Array  # (X,) pix², prior variances of the X-response terms νⱼ
    hold_tx: jax.Array = _padded("H", 0.0)  # (H,) rad, reported attitude of each hold
    hold_ty: jax.Array = _padded("H", 0.0)
    hold_T: jax.Array = _padded("H", 0.0)  # (H,) s, slew end to hold end
    hold_dir: jax.Array = _padded("H", 0.0)  # (H, 2) unit vector of the hold's tilt (x, y)
    mv_dir: jax.Array = _padded("H", 0.0)  # (H, 2) unit vector of the slew into each hold
    x_basis: jax.Array = _padded("H", 0.0)  # (H, X) pix, X-response columns at the holds
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
    mv_x_basis: jax.Array = _padded("HM", 0.0)  # (H, M, X) pix, X-response terms along slews

    def pad(self, H: int, N: int, M: int, Q: int | None = None) -> RecordData:
        """The same record laid out for H holds, N bins, M slew samples and Q shared
        angle-error columns (None: as it is).

        Exact: padded bins have ``mask`` False (zero weight), padded holds have no bins
        (``own``/``prev`` columns zero, so their β is its prior mean 0 and adds nothing to
        the residuals) and sit after the real ones (the unsettled-carry scan runs
        forwards), padded slew samples have ``mv_mask`` False, padded angle-error
        columns are zero (their β stays at its prior mean 0).
        """
        h0, n0, m0 = self.hold_tx.shape[0], self.y.shape[0], self.mv_tx.shape[1]
        q0 = self.angle_basis.shape[1]
        Q = q0 if Q is None else Q
        if H < h0 or N < n0 or M < m0 or Q < q0:
            raise ValueError(f"cannot pad ({h0}, {n0}, {m0}, {q0}) down to ({H}, {N}, {M}, {Q})")
        extra = {"H": H - h0, "N": N - n0, "M": M - m0, "Q": Q - q0}
        changes = {}
        for f in dataclasses.fields(self):
            if "pad" not in f.metadata:
                continue
            axes, fill = f.metadata["pad"]
            x = np.asarray(getattr(self, f.name))
            widths = [(0, extra[a]) for a in axes] + [(0, 0)] * (x.ndim - len(axes))
            changes[f.name] = np.pad(x, widths, constant_values=fill)
        return dataclasses.replace(self, **device_arrays(changes))

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

    def pad(self, H: int, N: int, M: int, S: int | None = None) -> RecordModel:
        """This record laid out for a larger structure (:meth:`RecordData.pad`); S is the
        number of systematic angle-error terms (None: as it is)."""
        s = self.structure
        S = s.n_systematic if S is None else S
        if (H, N, M, S) == (s.n_holds, s.n_bins, s.n_moves, s.n_systematic):
            return self
        if S < s.n_systematic:
            raise ValueError(f"cannot pad {s.n_systematic} systematic terms down to {S}")
        new = dataclasses.replace(s, n_holds=H, n_bins=N, n_moves=M, n_systematic=S)
        return dataclasses.replace(
            self, structure=new, data=self.data.pad(H, N, M, new.n_angle_cols)
        )

    def with_level(self, m_ref: Any) -> RecordModel:
        """This record with the level reference reading moved to ``m_ref`` (pix)."""
        return dataclasses.replace(self, data=self.data.with_level(m_ref))
