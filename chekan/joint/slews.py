"""The slews of a record, by type: what a term shared by all rounds along them is tied to.

Every round repeats the same slews (the same axis, start and end angles). A quantity that is
a fixed function of the platform's angle — an angle sensor's error, the X response beyond
eq. (6) — has one unknown contribution per slew type to the lag state after the slew,
shared by every round, whatever its shape between the commanded angles. The joint model
carries one term per type (:func:`chekan.joint.angles.slew_error_columns`,
:func:`chekan.joint.xresponse.x_response_path`) instead of continuing the holds' terms
between the commanded angles, which assumed a shape (linear between them) that a periodic
or graduation error of the sensor does not have.
"""

from __future__ import annotations

import numpy as np

from chekan.physics.units import ARCSEC_PER_RAD

GROUP_ARCSEC = 30.0  # start and end angles closer than this are the same (commanded angles)


def slew_types(theta_rad: np.ndarray, slew_axis: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """The type of the slew into each hold, numbered 0…T−1 in order of first appearance:
    its axis and its start and end angles (the holds' signed angles about that axis,
    grouped within ``GROUP_ARCSEC``); −1 where the hold is reached without a modelled slew
    (the first hold, or ``moved`` False: no slew samples)."""
    theta = np.asarray(theta_rad, dtype=float)
    step = np.round(theta * ARCSEC_PER_RAD / GROUP_ARCSEC).astype(np.int64)
    keys: dict[tuple[str, int, int], int] = {}
    out = np.full(theta.size, -1, dtype=np.int64)
    for k in range(1, theta.size):
        if moved[k]:
            key = (str(slew_axis[k]), int(step[k - 1]), int(step[k]))
            out[k] = keys.setdefault(key, len(keys))
    return out


def types_about(types: np.ndarray, slew_axis: np.ndarray, axis: str) -> tuple[np.ndarray, int]:
    """The types of the slews about ``axis`` renumbered 0…T−1 (−1 for the others), and T."""
    mine = (np.asarray(types) >= 0) & (np.asarray(slew_axis) == axis)
    uniq, local = np.unique(np.asarray(types)[mine], return_inverse=True)
    out = np.full(np.asarray(types).shape, -1, dtype=np.int64)
    out[mine] = local
    return out, int(uniq.size)


def type_indicator(kinds: np.ndarray, on: np.ndarray, n_types: int) -> np.ndarray:
    """(H, M, T) booleans: path sample m of the slew into hold k belongs to type t
    (``kinds`` (H,) from :func:`types_about`, ``on`` (H, M) the samples modelled)."""
    return (np.asarray(kinds)[:, None, None] == np.arange(n_types)) & np.asarray(on)[..., None]
