r"""The platform's angle sensors: what is known of their error, as the joint model uses it.

An angle sensor's error is mostly **systematic**: a fixed function of the angle
(graduation and interpolation errors, a scale error), the same in every round, plus a
smaller random part. The model carries both:

- the random part δₖ of every hold (prior N(0, σ_θ²), σ_θ a hyperparameter that the
  rounds' scatter estimates: Type A);
- the systematic part shared by all rounds, ζ_a at each commanded angle a (no shape
  assumed) and the scale error ξ·θₖ/θ_max. These repeat in every round, so the data
  cannot reveal them; their uncertainty reaches b through the prior (GUM Type B).

**Prior from the specification.** The platform's specification bounds the sensor error by
U (the paper: 3″). The error at an angle is the sum of several independent contributions
(graduation, interpolation, scale, zero offset), so values near the bound are less likely
than values near zero: we read the bound as a **triangular** distribution on [−U, U],
u = U/√6 (GUM 4.3.9); ``distribution="rectangular"`` gives the more conservative U/√3
(GUM 4.3.7). u is split equally between the per-angle part and the scale part at the
largest angle, ζ_a ~ N(0, u²/2) and ξ ~ N(0, u²/2), so that the systematic error at θ_max
has standard uncertainty u. Validated in ``docs/figures/validation_systematic.md``: with
the rectangular reading the intervals were 12–15 % too wide (mean z² 0.73–0.80) on
simulated platforms whose systematic error stays within 1.5–2″; with the triangular one
mean z² is near 1. A scale error of the sensor acts on b one to one (b ∝ 1/θ²: δb/b = −2ξ/θ_max),
which is why it is kept as its own term.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from chekan.errors import ChekanError
from chekan.units import ARCSEC_PER_RAD

DEFAULT_BOUND_ARCSEC = 3.0  # the paper: the platform reads its angles with an error ≤ 3″
HEADER_KEY = "platform_angle_bound_arcsec"
GROUP_ARCSEC = 30.0
DIVISORS = {
    "triangular": math.sqrt(6.0),
    "rectangular": math.sqrt(3.0),
}  # commanded angles closer than this are the same angle


@dataclass(frozen=True)
class AngleSensorSpec:
    """The platform angle sensors' specification: bound U of the systematic error (arcsec),
    how it is read (triangular or rectangular) and the share of its variance given to
    the scale error at the largest angle."""

    bound_arcsec: float = DEFAULT_BOUND_ARCSEC
    scale_share: float = 0.5
    distribution: str = "triangular"  # or "rectangular" (GUM 4.3.9, 4.3.7)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.bound_arcsec) and self.bound_arcsec >= 0):
            raise ChekanError(f"angle-sensor bound must be ≥ 0 arcsec, got {self.bound_arcsec}")
        if not 0.0 <= self.scale_share <= 1.0:
            raise ChekanError(f"scale share must be in [0, 1], got {self.scale_share}")
        if self.distribution not in DIVISORS:
            raise ChekanError(f"distribution must be one of {sorted(DIVISORS)}")

    @property
    def u_arcsec(self) -> float:
        """Standard uncertainty of the systematic error at θ_max: U/√6 (triangular) or
        U/√3 (rectangular)."""
        return self.bound_arcsec / DIVISORS[self.distribution]

    @property
    def per_angle_var(self) -> float:
        """Prior variance of ζ_a, arcsec²."""
        return self.u_arcsec**2 * (1.0 - self.scale_share)

    @property
    def scale_var(self) -> float:
        """Prior variance of ξ (the scale error expressed at θ_max), arcsec²."""
        return self.u_arcsec**2 * self.scale_share


def spec_for(meta: dict, bound_arcsec: float | None, source: str = "record") -> AngleSensorSpec:
    """The specification to use: ``bound_arcsec`` if given (CLI), else the header key
    ``platform_angle_bound_arcsec``, else the paper's 3″."""
    if bound_arcsec is not None:
        return AngleSensorSpec(float(bound_arcsec))
    raw = meta.get(HEADER_KEY)
    if raw is None:
        return AngleSensorSpec()
    try:
        value = float(raw)
    except ValueError:
        raise ChekanError(f"{source}: {HEADER_KEY}: not a number: {raw!r}") from None
    try:
        return AngleSensorSpec(value)
    except ChekanError as e:
        raise ChekanError(f"{source}: {HEADER_KEY}: {e}") from None


def commanded_groups(theta_rad: np.ndarray) -> np.ndarray:
    """Index of the commanded angle of every hold (signed angles about the program axis
    within ``GROUP_ARCSEC`` are one angle; level is one angle too)."""
    arcsec = np.asarray(theta_rad, dtype=float) * ARCSEC_PER_RAD
    keys = np.round(arcsec / GROUP_ARCSEC).astype(np.int64)
    _, inverse = np.unique(keys, return_inverse=True)
    return inverse.reshape(-1)


@dataclass(frozen=True)
class SystematicBasis:
    """The systematic angle error as a function of the angle: ζ at the commanded angles
    (``nodes_rad``, sorted; hat functions, so at a commanded angle only its own ζ acts and
    between two of them the error is interpolated linearly — what the slews see), then
    the scale error ξ·θ/θ_max."""

    nodes_rad: np.ndarray
    theta_max_rad: float

    @classmethod
    def for_holds(cls, theta_rad: np.ndarray) -> SystematicBasis:
        """The basis of a record's holds (their commanded angles)."""
        theta = np.asarray(theta_rad, dtype=float)
        group = commanded_groups(theta)
        nodes = np.array([theta[group == a].mean() for a in range(int(group.max()) + 1)])
        return cls(np.sort(nodes), max(float(np.max(np.abs(theta))), 1e-9))

    @property
    def size(self) -> int:
        return self.nodes_rad.size + 1

    def at(self, theta_rad: np.ndarray) -> np.ndarray:
        """Basis values (..., A + 1) at angles ``theta_rad`` (clamped beyond the ends)."""
        theta = np.asarray(theta_rad, dtype=float)
        eye = np.eye(self.nodes_rad.size)
        hats = [np.interp(theta, self.nodes_rad, eye[a]) for a in range(eye.shape[0])]
        return np.concatenate([np.stack(hats, -1), (theta / self.theta_max_rad)[..., None]], -1)

    def prior_var(self, spec: AngleSensorSpec) -> np.ndarray:
        """Prior variances of (ζ, ξ), arcsec² (a zero bound: a tiny variance keeps the
        normal equations regular)."""
        A = self.nodes_rad.size
        return np.maximum(np.concatenate([np.full(A, spec.per_angle_var), [spec.scale_var]]), 1e-12)


def systematic_basis(theta_rad: np.ndarray, spec: AngleSensorSpec) -> tuple[np.ndarray, np.ndarray]:
    """The systematic angle-error basis at the holds (H, A + 1) and its prior variances:
    one column per commanded angle (an indicator at the holds), then θₖ/θ_max."""
    basis = SystematicBasis.for_holds(theta_rad)
    return basis.at(theta_rad), basis.prior_var(spec)


def angle_sensor_entry(spec: AngleSensorSpec | None) -> dict:
    """The result's ``angle_sensor``: how the platform's angle errors were modelled."""
    if spec is None:
        return {"model": "independent"}
    return {
        "model": "systematic",
        "bound_arcsec": spec.bound_arcsec,
        "distribution": spec.distribution,
        "u_per_angle_arcsec": math.sqrt(spec.per_angle_var),
        "u_scale_arcsec": math.sqrt(spec.scale_var),
    }
