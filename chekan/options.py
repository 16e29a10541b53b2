"""Options of one calibration, typed and built at the edge (CLI, archive, validation)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

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
    # map/bayes: the platform's angle-sensor error. "systematic": a part per commanded angle
    # and a scale error shared by all rounds (prior from the specification, Type B) plus a
    # random part per hold; "independent": every hold's error independent (before 0.2).
    angle_errors: str = "systematic"
    angle_bound_arcsec: float | None = None  # None: the record's header, else 3″ (the paper)
    # map/bayes on records: the MAP's numerics. "gn": Gauss–Newton passes, with
    # Levenberg–Marquardt where one fails, and the EM between passes compiled (0.3.1,
    # fast); "lm": LM passes and the host EM with SciPy's M-step (0.2; the MAP moves by
    # < 0.01 sd between the two: the regression snapshot keeps "lm")
    map_solver: Literal["gn", "lm"] = "gn"

    def angle_spec(self, meta: dict, source: str = "record"):
        """The angle-sensor specification for a record with header ``meta`` (None for
        independent angle errors)."""
        from chekan.joint.angles import spec_for

        if self.angle_errors == "independent":
            return None
        return spec_for(meta, self.angle_bound_arcsec, source)
