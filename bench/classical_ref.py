"""A plain-NumPy classical fit, written from the paper, as the reference for the benchmark.

Independent of :mod:`chekan.records.holds` and :mod:`chekan.classical.fit` (which it must agree
with):
hold means after settling, the level reading interpolated in time between the level holds
around each round, m − m_h of each ± pair mean (eq. 25) and one least squares of
Δg = b (m − m_h) + a (m − m_h)² (eq. 21) with b per round and system and one common a.
Assumes a clean record: one run per step, tilts about one axis, level steps around rounds.
"""

from __future__ import annotations

import numpy as np

from chekan.physics.units import ARCSEC_PER_RAD


def numpy_classical_fit(record, settle_s: float) -> tuple[np.ndarray, float]:
    """``(b (rounds, 2) in mGal/pix, a in mGal/pix²)`` of a record, record convention."""
    step = np.asarray(record.step)
    t = np.asarray(record.t_s, dtype=np.float64)
    m = np.stack([record.m1_pix, record.m2_pix], axis=1).astype(np.float64)
    tx = np.asarray(record.tilt_x_arcsec, dtype=np.float64) / ARCSEC_PER_RAD
    ty = np.asarray(record.tilt_y_arcsec, dtype=np.float64) / ARCSEC_PER_RAD
    holds = []  # (t_mid, m (2,), 1 − cos tx cos ty, signed tilt angle in degrees)
    for s in np.unique(step[step >= 0]):
        i = np.flatnonzero(step == s)
        i = i[t[i] - t[i[0]] >= settle_s]
        hx, hy = 2 * np.sin(tx[i].mean() / 2) ** 2, 2 * np.sin(ty[i].mean() / 2) ** 2
        theta = ty[i].mean() if abs(ty[i].mean()) >= abs(tx[i].mean()) else tx[i].mean()
        holds.append((t[i].mean(), m[i].mean(axis=0), hx + hy - hx * hy, np.rad2deg(theta)))
    level = [abs(h[3]) < 0.1 for h in holds]
    xs, ys, cols = [], [], []  # pair means m − m_h, reference Δg, column round·2 + system
    r = 0
    for k in range(1, len(holds)):
        if not level[k - 1] or level[k]:
            continue  # a round starts after a level hold
        e = k
        while not level[e]:
            e += 1
        (t0, m0, h0, _), (t1, m1, h1, _) = holds[k - 1], holds[e]
        tilts = holds[k:e]
        for mag in sorted({round(abs(h[3]), 1) for h in tilts}):
            pair = [h for h in tilts if round(abs(h[3]), 1) == mag]
            x = np.mean([h[1] - (m0 + (h[0] - t0) / (t1 - t0) * (m1 - m0)) for h in pair], 0)
            dh = np.mean([h[2] for h in pair if h[3] > 0]) / 2
            dh += np.mean([h[2] for h in pair if h[3] < 0]) / 2
            for s in range(2):
                xs.append(x[s])
                ys.append(-record.g_local_mgal * (dh - (h0 + h1) / 2))
                cols.append(2 * r + s)
        r += 1
    x_pix, dg_mgal, col = np.array(xs), np.array(ys), np.array(cols)
    X = np.zeros((x_pix.size, 2 * r + 1))
    X[np.arange(x_pix.size), col] = x_pix
    X[:, -1] = x_pix**2
    coef = np.linalg.lstsq(X, dg_mgal, rcond=None)[0]
    return coef[:-1].reshape(r, 2), float(coef[-1])
