"""From a record to the joint model's layout: holds, bin means, slews.

The data are **bin means of the raw 1 Hz samples inside every hold**: short bins across
the settling transient (edges 0, 15, 40, 90, 180 s, then ``settle_s``) and one long bin
after it. Modelling the damping lag lets us keep the settling samples (they carry τ),
while binning keeps the likelihood small (≈ 6 bins × 36 holds × 2 systems instead of
66 000 samples). A bin mean of n samples has noise variance (sⱼ σⱼ)²/n, σⱼ estimated
from the first differences of the settled samples (robust: 1.4826·MAD/√2).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from chekan.jaxconfig import device_arrays
from chekan.joint.angles import AngleSensorSpec, SensorReads, all_sensor_terms
from chekan.joint.layout import ModelStructure, RecordData, RecordModel
from chekan.joint.slews import slew_types, types_about
from chekan.joint.xresponse import M0_TOLERANCE_PIX, x_response_terms
from chekan.physics.units import ARCSEC_PER_RAD
from chekan.records.holds import (
    GAP_PERIODS,
    HoldTable,
    gap_before,
    sample_period_s,
    segment_record,
    settle_of,
)

BIN_EDGES_S = (0.0, 15.0, 40.0, 90.0, 180.0)


def prepare(
    record,
    settle_s: float | None,
    *,
    holds: HoldTable | None = None,
    encoder: bool = False,
    angle_spec: AngleSensorSpec | None = None,
    angle_spec_x: AngleSensorSpec | None = None,
    horizontal_u_pix: float = M0_TOLERANCE_PIX,
):
    """Segment the record into holds and lay it out: ``(holds, RecordModel)``.

    ``settle_s`` None: the record's ``program_settle_s``, else 300 s; ``holds``: the
    record's holds where found already (:func:`chekan.records.inputs.ready_input`; then
    ``settle_s`` is theirs). The level reference
    starts at the classical m_h (mean of the level holds). ``angle_spec`` None: angle
    errors independent per hold (the model before systematic errors); otherwise the
    systematic part shared by all rounds is modelled with that prior (:mod:`.angles`).
    ``horizontal_u_pix``: the pendulums' horizontal about the CCD centre, standard
    uncertainty (:mod:`.xresponse`; records about X).
    """
    if holds is None:
        holds = segment_record(record, settle_s=settle_of(record, settle_s))
    m_ref = np.nanmean(holds.m_mean_pix[holds.is_level], axis=0)
    return holds, prepare_record(
        record,
        holds,
        m_ref,
        encoder=encoder,
        angle_spec=angle_spec,
        angle_spec_x=angle_spec_x,
        horizontal_u_pix=horizontal_u_pix,
    )


def _robust_sigma(record, holds: HoldTable) -> np.ndarray:
    """Per-sample noise of each system from first differences of settled samples."""
    m = np.stack([record.m1_pix, record.m2_pix], axis=1)
    t = np.asarray(record.t_s, dtype=float)
    out = np.zeros(2)
    period = sample_period_s(t, record.sample_rate_hz)
    for j in range(2):
        diffs = []
        for k, a in enumerate(holds.start):
            sel = a + np.flatnonzero(holds.settled(k, t))
            d = np.diff(m[sel, j])
            near = np.diff(t[sel]) <= GAP_PERIODS * period  # not across a gap
            diffs.append(d[np.isfinite(d) & near])
        d = np.concatenate(diffs) if diffs else np.zeros(0)
        mad = np.median(np.abs(d - np.median(d))) if d.size else np.nan
        out[j] = 1.4826 * mad / math.sqrt(2.0) if d.size > 10 and mad > 0 else 0.1
    return out


def _moves(record, holds: HoldTable, dt_s: float):
    """Samples of the slew into each hold (reported attitude) and their lag exponents.

    Returns per hold k (padded to the longest slew, M): tx, ty (H, M) rad, ``lag`` (H, M)
    = t_last − tᵢ (s) with t_last the last sample before the hold, ``mask`` (H, M), and
    t_last (H,). The lag state at t_last is exactly
    y = (1 − Σᵢwᵢ) Eₖ₋₁ + Σᵢ wᵢ E(θᵢ), wᵢ = (1 − e^{−Δt/τ}) e^{−lagᵢ/τ}.
    """
    t = np.asarray(record.t_s, dtype=float)
    tx = np.asarray(record.tilt_x_arcsec, dtype=float) / ARCSEC_PER_RAD
    ty = np.asarray(record.tilt_y_arcsec, dtype=float) / ARCSEC_PER_RAD
    H = holds.n
    idx = [
        np.arange(holds.stop[k - 1], holds.start[k]) if k else np.zeros(0, int) for k in range(H)
    ]
    idx = [i[np.isfinite(tx[i]) & np.isfinite(ty[i])] for i in idx]
    M = max(1, max(i.size for i in idx))
    mx, my, lag = np.zeros((H, M)), np.zeros((H, M)), np.zeros((H, M))
    mask = np.zeros((H, M), bool)
    t_last = np.array(
        [t[holds.start[k] - 1] if holds.start[k] > 0 else t[0] - 1e9 for k in range(H)]
    )
    for k, i in enumerate(idx):
        n = i.size
        mx[k, :n], my[k, :n] = tx[i], ty[i]
        lag[k, :n] = t_last[k] - t[i]
        mask[k, :n] = True
    return mx, my, lag, mask, t_last


SETTLED_D0_S = 1e9  # a bin's time since the slew where the model takes the state as settled


def _bin(k: int, m, ts, d0: float) -> tuple:
    """One bin of hold k: ``(hold, mean (2), count (2), d0, dstep, n_t, t_mid)``."""
    cnt = np.sum(np.isfinite(m), axis=0)
    with np.errstate(invalid="ignore"):
        mean = np.where(cnt > 0, np.nansum(m, axis=0) / np.maximum(cnt, 1), 0.0)
    dstep = (ts[-1] - ts[0]) / (ts.size - 1) if ts.size > 1 else 1.0
    return (k, mean, cnt, d0, dstep, ts.size, ts.mean())


def _bin_rows(t, m, holds: HoldTable, t_last, bin_edges_s, gap: np.ndarray) -> list[tuple]:
    """The bins of every hold: ``(hold, mean (2), count (2), d0, dstep, n_t, t_mid)``, the
    settling part cut at ``bin_edges_s``, the settled part one bin. After a gap that leaves
    the sensor's state unknown (:mod:`chekan.records.holds`) the samples are not used until it has
    settled, and each run of samples without a gap after that is one bin: of the settled
    state (``d0`` = :data:`SETTLED_D0_S`) where the hold's start was not seen, else with the
    lag still followed from its slew; a bin never spans a gap (``gap``: per row, samples
    lost just before it, :func:`chekan.records.holds.gap_before`)."""
    rows = []
    for k in range(holds.n):
        a, b = holds.start[k], holds.stop[k]
        tt = t[a:b]
        known = np.ones(b - a, bool) if holds.known is None else holds.known[a:b]
        lost = np.concatenate([[False], gap[a + 1 : b]])
        run = np.cumsum(lost)  # runs of samples without a gap
        # before the first unknown state: the lag followed from the slew, bins cut at gaps
        brk = np.flatnonzero(~known)
        n_plain = int(brk[0]) if brk.size else tt.size
        rel = tt[:n_plain] - tt[0]
        edges = sorted({e for e in bin_edges_s if e < holds.settle_s} | {holds.settle_s})
        edges = [e for e in edges if rel.size and e <= rel[-1]] + [np.inf]
        for lo, hi in itertools.pairwise(edges):
            inside = np.flatnonzero((rel >= lo) & (rel < hi))
            for r in np.unique(run[inside]):
                sel = inside[run[inside] == r]
                rows.append(_bin(k, m[a:b][sel], tt[sel], tt[sel[0]] - t_last[k]))
        # after it: runs of known samples, the state settled where the start was not seen,
        # else the lag still followed from the slew
        use = np.flatnonzero(known[n_plain:]) + n_plain
        part = np.cumsum(lost | ~known)[use]
        fresh = holds.restarted(k)
        for r in np.unique(part):
            sel = use[part == r]
            d0 = SETTLED_D0_S if fresh else tt[sel[0]] - t_last[k]
            rows.append(_bin(k, m[a:b][sel], tt[sel], d0))
    return rows


def _slew_axis(holds: HoldTable) -> np.ndarray:
    """The axis of the slew into each hold: that of the tilt it reaches or leaves (a slew
    between a level hold and a tilt moves about the tilt's axis)."""
    axis = np.asarray(holds.hold_axis).copy()
    for k in range(1, holds.n):
        if holds.is_level[k] and not holds.is_level[k - 1]:
            axis[k] = holds.hold_axis[k - 1]
    return axis


def _angle_bases(
    holds: HoldTable,
    mv_tx,
    mv_ty,
    mv_mask,
    slew_axis: np.ndarray,
    types: np.ndarray,
    L: int,
    specs: dict[str, AngleSensorSpec | None],
):
    """The shared angle-error columns at the holds and along the slews, their prior
    variances, how many are systematic, how many of those are the X sensor's and how many
    are common to both: ``L`` legacy encoder terms (N(0, 2″)), then the systematic terms of
    every sensor that reads holds of this record (:func:`chekan.joint.angles.all_sensor_terms`:
    the scale error both may share, the X sensor's, the Y sensor's: one term per commanded
    angle and the scale error at the holds, the scale error and one term per slew type
    along the slews, ``types``)."""
    theta = holds.theta_rad
    tmax = max(np.max(np.abs(theta)), 1e-9)
    H = theta.shape[0]
    enc = np.polynomial.legendre.legvander(theta / tmax, L)[:, 1:] if L else np.zeros((H, 0))
    hold_axis = np.asarray(holds.hold_axis)
    sensors = {}
    for axis in ("x", "y"):
        spec = specs.get(axis)
        on = hold_axis == axis
        if spec is None or not np.any(on & ~holds.is_level):
            continue
        kinds, T = types_about(types, slew_axis, axis)
        sensors[axis] = SensorReads(
            on,
            mv_tx if axis == "x" else mv_ty,
            (slew_axis == axis)[:, None] & mv_mask,
            kinds,
            T,
            spec,
        )
    hold, path, var, n_common, n_x = all_sensor_terms(theta, sensors, mv_tx.shape)
    return (
        np.concatenate([enc, hold], axis=1),
        np.concatenate([np.full(L, 4.0), var]),
        np.concatenate([np.zeros((*mv_tx.shape, L)), path], axis=-1),  # legacy: holds only
        hold.shape[1],
        n_x,
        n_common,
    )


def _directions(axis: np.ndarray) -> np.ndarray:
    """(H, 2) unit vectors (x, y) of tilts about each axis."""
    return np.where((np.asarray(axis) == "x")[:, None], [1.0, 0.0], [0.0, 1.0])


def _bin_fields(rows: list, H: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The bins' fields of :class:`RecordData` (which hold each bin lies in and the one
    before it, d0, spacing, samples, means, counts, mask) and the bins' mid-times (s)."""
    N = len(rows)
    hold_of = np.array([r[0] for r in rows])
    own = np.zeros((N, H))
    own[np.arange(N), hold_of] = 1.0
    prev = np.zeros((N, H))
    has_prev = hold_of > 0
    prev[np.flatnonzero(has_prev), hold_of[has_prev] - 1] = 1.0
    cnt = np.stack([r[2] for r in rows]).astype(float)
    d0 = np.array([r[3] for r in rows])
    fields: dict[str, np.ndarray] = {
        "own": own,
        "prev": prev,
        "bin_hold": hold_of.astype(np.int32),
        "d0": np.where(hold_of > 0, d0, SETTLED_D0_S),  # first hold: settled from the start
        "dstep": np.array([r[4] for r in rows]),
        "n_t": np.array([r[5] for r in rows], dtype=float),
        "y": np.stack([r[1] for r in rows]),
        "cnt": cnt,
        "mask": cnt > 0,
    }
    return fields, np.array([r[6] for r in rows])


def _x_terms(record, holds: HoldTable, mv_tx, mv_mask, slew_axis, types, m_level_ref, u_pix):
    """The X rounds' response columns at the holds and along the slews about X, and their
    prior variances (:func:`chekan.joint.xresponse.x_response_terms`)."""
    x_kinds, x_types = types_about(types, slew_axis, "x")
    return x_response_terms(
        holds.theta_rad,
        holds.hold_axis,
        float(record.g_local_mgal),
        mv_tx,
        (slew_axis == "x")[:, None] & mv_mask,
        x_kinds,
        x_types,
        m_level_pix=float(np.mean(m_level_ref)),
        m0_pix=float(record.ccd_center_pix),
        m0_u_pix=u_pix,
    )


def prepare_record(
    record,
    holds: HoldTable,
    m_level_ref: np.ndarray,
    *,
    drift_degree: int = 3,
    encoder: bool = False,
    angle_spec: AngleSensorSpec | None = None,
    angle_spec_x: AngleSensorSpec | None = None,
    bin_edges_s=BIN_EDGES_S,
    horizontal_u_pix: float = M0_TOLERANCE_PIX,
) -> RecordModel:
    """Bin the samples of every hold and build the model's data pytree (``angle_spec``:
    the Y sensor's, ``angle_spec_x`` the X sensor's, used where the record tilts about X;
    ``horizontal_u_pix``: the pendulums' horizontal about the CCD centre, :mod:`.xresponse`)."""
    t = np.asarray(record.t_s, dtype=float)
    m = np.stack([record.m1_pix, record.m2_pix], axis=1).astype(float)
    H = holds.n
    dt_s = 1.0 / float(record.sample_rate_hz)
    mv_tx, mv_ty, mv_lag, mv_mask, t_last = _moves(record, holds, dt_s)
    # time from the end of the slew into hold k to the hold's last sample (lag carried on)
    hold_T = np.array([t[holds.stop[k] - 1] - t_last[k] if k else 0.0 for k in range(H)])
    # a hold whose start a gap hid ends settled: nothing of its slew carries on
    if holds.fresh is not None:
        hold_T = np.where(holds.fresh, SETTLED_D0_S, hold_T)
    rows = _bin_rows(t, m, holds, t_last, bin_edges_s, gap_before(t, record.sample_rate_hz))
    bins, t_mid = _bin_fields(rows, H)
    t0, t1 = float(t.min()), float(t.max())
    s = 2.0 * (t_mid - t0) / max(t1 - t0, 1.0) - 1.0
    P = np.polynomial.legendre.legvander(s, drift_degree)[:, 1:]  # no constant
    L = 3 if encoder else 0
    specs = {"y": angle_spec, "x": angle_spec_x}
    slew_axis = _slew_axis(holds)
    types = slew_types(holds.theta_rad, slew_axis, mv_mask.any(axis=1))
    basis, prior_var, mv_basis, S, S_x, S_c = _angle_bases(
        holds, mv_tx, mv_ty, mv_mask, slew_axis, types, L, specs
    )
    x_basis, mv_x_basis, x_prior_var = _x_terms(
        record, holds, mv_tx, mv_mask, slew_axis, types, m_level_ref, horizontal_u_pix
    )
    # placed on the device in one call (one per array costs ~0.1 ms each, 26 arrays)
    arrays = {
        "g": np.asarray(record.g_local_mgal, dtype=np.float64),
        "m0": np.asarray(record.ccd_center_pix, dtype=np.float64),
        "m_ref": np.asarray(m_level_ref, dtype=np.float64),
        "hold_tx": np.asarray(holds.tilt_x_rad),
        "hold_ty": np.asarray(holds.tilt_y_rad),
        "hold_dir": _directions(holds.hold_axis),
        "mv_dir": _directions(slew_axis),
        "x_basis": x_basis,
        "x_prior_var": x_prior_var,
        "mv_x_basis": mv_x_basis,
        **bins,
        "mv_tx": np.asarray(mv_tx),
        "mv_ty": np.asarray(mv_ty),
        "mv_lag": np.asarray(mv_lag),
        "mv_mask": np.asarray(mv_mask),
        "dt": np.asarray(dt_s),
        "hold_T": np.asarray(hold_T),
        "drift_basis": np.asarray(P),
        "angle_basis": np.asarray(basis),
        "angle_prior_var": np.asarray(prior_var),
        "mv_angle_basis": np.asarray(mv_basis),
        "sigma_base": np.asarray(_robust_sigma(record, holds)),
        "hold_mask": np.ones(H, dtype=bool),  # False for padding (see RecordData.pad)
    }
    data = RecordData(**device_arrays(arrays))
    structure = ModelStructure(H, len(rows), mv_tx.shape[1], drift_degree, L, S, x_basis.shape[1])
    return RecordModel(
        structure,
        data,
        holds.step,
        t_mid,
        (t0, t1),
        angle_spec if S > S_x + S_c else None,
        angle_spec_x if S_x else None,
        S_x,
        horizontal_u_pix,
    )
