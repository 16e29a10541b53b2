"""Options of one calibration, typed and built at the edge (CLI, archive, validation)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from chekan.errors import ChekanError

METHODS = ("classical", "map", "bayes")
ANGLE_ERRORS = ("systematic", "independent")


@dataclass(frozen=True)
class CalibrationOptions:
    """How to calibrate one record or protocol."""

    method: str = "classical"
    hdi_prob: float = 0.95
    settle_s: float | None = None  # None: the record's program_settle_s, else 300 s
    a_fixed: float | None = None  # record convention, mGal/pix²
    netcdf: str | Path | None = None  # bayes: where to write the ArviZ posterior
    seed: int = 0
    progress: bool = True
    encoder_error: bool = False  # bayes/map: smooth systematic angle error per commanded angle
    quick: bool = False  # bayes: cap the sampler at 3000 steps (tests, demos)
    # bayes: "auto" draws the posterior by importance sampling from the fitted proposal where
    # that is reliable (PSIS k̂ < 0.7, ESS ≥ 1000 for every reported quantity), else runs
    # emcee; "emcee": emcee always (the reference)
    sampler: Literal["auto", "emcee"] = "auto"
    # map/bayes: the platform's angle-sensor error. "systematic": a part per commanded angle
    # and a scale error shared by all rounds (prior from the specification, Type B) plus a
    # random part per hold; "independent": every hold's error independent (before 0.2).
    angle_errors: str = "systematic"
    angle_bound_arcsec: float | None = None  # None: the record's header, else 3″ (the paper)
    # how the bound is read: "rectangular" (GUM 4.3.7, the default: only a bound is known)
    # or "triangular" (GUM 4.3.9; for comparisons in validation studies)
    angle_bound_reading: str = "rectangular"
    # the platform's own angle calibration (chekan.records.anglecal): a file, or the table read from
    # one; None: the record header's angle_calibration, if any
    angle_calibration: str | Path | Any = None
    # map/bayes on records about X: the standard uncertainty (pix) of each pendulum's
    # horizontal about the CCD centre (chekan.joint.xresponse); None: 100 pix, the model's
    # own assumption (5 % of the CCD), for want of the instrument's figure
    horizontal_u_pix: float | None = None
    # map/bayes on records: the MAP's numerics. "gn": Gauss–Newton passes, with
    # Levenberg–Marquardt where one fails, and the EM between passes compiled (0.3.1,
    # fast); "lm": LM passes and the host EM with SciPy's M-step (0.2; the MAP moves by
    # < 0.01 sd between the two: the regression snapshot keeps "lm")
    map_solver: Literal["gn", "lm"] = "gn"

    def __post_init__(self) -> None:
        u = self.horizontal_u_pix
        if u is not None and not (math.isfinite(u) and u > 0):
            raise ChekanError(
                f"--horizontal-u-pix {u:g}: the pendulums' horizontal must have a standard "
                "uncertainty > 0 pix (a horizontal known exactly is not a prior the model "
                "can carry; give a small number, such as 0.1)"
            )

    def angle_spec(self, meta: dict, source: str = "record", calibration=None, axis: str = "y"):
        """What is known of the ``axis`` angle sensor of a record with header ``meta`` and
        the angle calibration applied to it (None for independent angle errors)."""
        from chekan.joint.angles import spec_for

        if self.angle_errors == "independent":
            return None
        return spec_for(
            meta,
            self.angle_bound_arcsec,
            source,
            axis=axis,
            calibration=calibration,
            reading=self.angle_bound_reading,
        )
