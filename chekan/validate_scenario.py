"""The scenario of a validation study: what the simulated platform's angle sensors do
(systematic and random errors) and what the model assumes of them; the instrument of a
session per case."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Scenario:
    """What the simulated platform does and what the model assumes of it.

    ``systematic_arcsec``: bound of the simulated systematic angle-sensor error (0: none;
    :func:`chekan.simulate.systematic_angle_error`), ``shape`` its shape;
    ``random_arcsec``: (low, high) of the random angle error's sd, drawn per session
    (None: the simulator's 2″); ``angle_errors`` and ``angle_bound_arcsec``: the model's
    (:class:`chekan.options.CalibrationOptions`).
    """

    systematic_arcsec: float = 1.5
    shape: str = "mixed"
    random_arcsec: tuple[float, float] | None = None
    angle_errors: str = "systematic"
    angle_bound_arcsec: float | None = None

    def options(self, **kw):
        from chekan.options import CalibrationOptions

        return CalibrationOptions(
            angle_errors=self.angle_errors, angle_bound_arcsec=self.angle_bound_arcsec, **kw
        )


DEFAULT_SCENARIO = Scenario()


def session_truth(case: str, rng: np.random.Generator, i: int, scenario: Scenario):
    from chekan.simulate import random_truth

    kw: dict[str, Any] = {
        "angle_systematic_arcsec": scenario.systematic_arcsec,
        "angle_systematic_shape": scenario.shape,
    }
    if case == "misaligned":
        kw.update(
            eps_arcmin=tuple(rng.choice([-1, 1], 2) * rng.uniform(8, 10, 2)),
            dgamma_arcmin=float(rng.choice([-1, 1]) * rng.uniform(15, 20)),
        )
    elif case == "drift":
        kw.update(drift_pix_per_h=tuple(rng.choice([-1, 1], 2) * 0.3))
    elif case == "slow":
        kw.update(tau_s=90.0)
    truth = random_truth(rng, serial=f"V{i}", **kw)
    if scenario.random_arcsec is not None:  # its own stream: the rest of the session stays
        lo, hi = scenario.random_arcsec
        truth.angle_error_sd_arcsec = float(np.random.default_rng([i, 0xA]).uniform(lo, hi))
    return truth


def scenario_line(sc: dict | None) -> str:
    if not sc:
        return "—"
    sim = (
        f"systematic ≤ {sc['systematic_arcsec']:g}″ ({sc['shape']})"
        if sc["systematic_arcsec"] > 0
        else "no systematic error"
    )
    rnd = (
        "random 2″"
        if sc["random_arcsec"] is None
        else "random {:g}–{:g}″".format(*sc["random_arcsec"])
    )
    bound = sc["angle_bound_arcsec"]
    model = sc["angle_errors"] + (
        "" if sc["angle_errors"] != "systematic" else f", bound {bound if bound else 3:g}″"
    )
    return f"{sim}, {rnd}; model: {model}"
