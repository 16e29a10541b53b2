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
U per axis (the paper: 3″). With only a bound known, GUM 4.3.7 reads it as a
**rectangular** distribution on [−U, U], u = U/√3: a certificate must hold for every
platform that the specification admits, including one whose error reaches the bound
(validation: with the triangular reading, U/√6, 95 % intervals covered 0.80 of such
platforms; ``docs/figures/validation_edge.md``). ``distribution="triangular"`` remains for
a platform whose maker shows that its error sums several independent contributions.
The bound does not say how the error depends on the angle: a pure scale error reaching
U at θ_max and errors independent from angle to angle, each reaching U, are both admitted.
Both extremes are carried, each with the full u² (as for a calibration table, below):
ζ_a ~ N(0, u²) and ξ ~ N(0, u²). A scale error of the sensor acts on b one to one
(b ∝ 1/θ²: δb/b = −2ξ/θ_max), which is why it is its own term; with the full u² on it the
expanded uncertainty (k = 2) of b still covers a platform whose error is a pure scale
error at the bound (2/√3 > 1), which a split of u² between the two parts did not
(validation of the designer's program at the edge of the specification: |z| up
to 2.8 on such platforms; ``docs/figures/validation_dual.md``).

**Prior from the platform's own calibration** (:mod:`chekan.records.anglecal`). The corrections
are applied to the measured angles; what is left is the calibration's uncertainty,
u(θ) = U(θ)/2 (k = 2, normal), which replaces the bound. A table alone does not state how
the errors of its angles correlate, so both extremes are carried: ζ_a ~ N(0, u(θ_a)²)
(independent) and ξ ~ N(0, u(θ_max)²) (fully correlated, the scale). Where the lab states
the part of U that is a scale error (U_s at the table's largest angle θ_t,
``scale_part_<axis>_arcsec``), that knowledge replaces the extremes: ξ ~ N(0, u_s(θ_max)²) and
ζ_a ~ N(0, u(θ_a)² − u_s(θ_a)²), u_s(θ) = (U_s/2)·|θ|/θ_t.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from chekan.errors import ChekanError
from chekan.joint.slews import type_indicator
from chekan.physics.units import ARCSEC_PER_RAD

DEFAULT_BOUND_ARCSEC = 3.0  # the paper: the platform reads its angles with an error ≤ 3″
HEADER_KEY = "platform_angle_bound_arcsec"  # both sensors
AXIS_KEYS = {"x": "platform_angle_bound_x_arcsec", "y": "platform_angle_bound_y_arcsec"}
GROUP_ARCSEC = 30.0  # commanded angles closer than this are the same angle
DIVISORS = {"rectangular": math.sqrt(3.0), "triangular": math.sqrt(6.0)}
READING = {
    "rectangular": "rectangular, u = U/√3 (GUM 4.3.7: only a bound is known)",
    "triangular": "triangular, u = U/√6 (GUM 4.3.9)",
    "calibration": "the platform's angle calibration, u = U/2 (k = 2, normal)",
}
DEFAULT_SOURCE = "the paper's specification of the platform (3″)"


@dataclass(frozen=True)
class AngleSensorSpec:
    """What is known of one angle sensor's systematic error: the specification's bound U
    (arcsec) and how it is read, or the platform's own calibration table of that axis
    (which then replaces the bound); ``scale_share``: None (both extremes, each with the
    full u², the default) or the share of u² given to the scale error, the rest to the
    per-angle part (constructed cases: 1.0 a pure scale error, 0.0 none); where the
    knowledge comes from (stated in the result)."""

    bound_arcsec: float = DEFAULT_BOUND_ARCSEC
    scale_share: float | None = None
    distribution: str = "rectangular"  # or "triangular" (GUM 4.3.7, 4.3.9)
    axis: str = "y"
    source: str = DEFAULT_SOURCE
    calibration: Any = None  # chekan.records.anglecal.AngleCalibration of this sensor, if any

    def __post_init__(self) -> None:
        if not (math.isfinite(self.bound_arcsec) and self.bound_arcsec >= 0):
            raise ChekanError(f"angle-sensor bound must be ≥ 0 arcsec, got {self.bound_arcsec}")
        if self.scale_share is not None and not 0.0 <= self.scale_share <= 1.0:
            raise ChekanError(f"scale share must be in [0, 1], got {self.scale_share}")
        if self.distribution not in DIVISORS:
            raise ChekanError(f"distribution must be one of {sorted(DIVISORS)}")

    @property
    def table(self):
        """The calibration table of this sensor's axis (None: the bound is used)."""
        return None if self.calibration is None else self.calibration.table(self.axis)

    @property
    def u_arcsec(self) -> float:
        """Standard uncertainty of the systematic error at θ_max: U/√3 (rectangular) or
        U/√6 (triangular); with a calibration table, the largest U/2 of its rows."""
        if self.table is not None:
            return float(np.max(self.table.U_arcsec)) / 2.0
        return self.bound_arcsec / DIVISORS[self.distribution]

    @property
    def reading(self) -> str:
        """How the knowledge is read, in words (the result and the certificate state it)."""
        if self.stated_scale:
            return READING["calibration"] + (
                f"; of it a scale error U = {self.table.scale_U_arcsec:g}″ at "
                f"{self.table.max_angle_arcsec:g}″, the rest independent per angle (stated)"
            )
        return READING["calibration" if self.table is not None else self.distribution]

    def u_at(self, theta_rad: np.ndarray) -> np.ndarray:
        """Standard uncertainty of the systematic error at angles ``theta_rad``, arcsec."""
        theta = np.asarray(theta_rad, dtype=float)
        if self.table is None:
            return np.full(theta.shape, self.u_arcsec)
        return self.table.u_at(theta * ARCSEC_PER_RAD)

    @property
    def stated_scale(self) -> bool:
        """Whether the calibration table states the part of its U that is a scale error
        (:class:`chekan.records.anglecal.AxisTable`): then that part is the scale term's and the
        rest the per-angle terms', instead of both extremes."""
        return self.table is not None and self.table.scale_U_arcsec is not None

    @property
    def per_angle_var(self) -> float:
        """Prior variance of ζ_a, arcsec² (the largest over a table's rows)."""
        if self.stated_scale:
            return float(np.max(self.angle_var_at(self.table.angle_arcsec / ARCSEC_PER_RAD)))
        return self.u_arcsec**2 * self.shares[0]

    @property
    def scale_var(self) -> float:
        """Prior variance of ξ (the scale error expressed at θ_max), arcsec²."""
        if self.stated_scale:
            return (self.table.scale_U_arcsec / 2.0) ** 2
        return self.u_arcsec**2 * self.shares[1]

    def angle_var_at(self, theta_rad: np.ndarray) -> np.ndarray:
        """Prior variance of the per-angle error at ``theta_rad``, arcsec²: the per-angle
        share of u(θ)², or with a stated scale part u(θ)² − u_s(θ)²."""
        u = self.u_at(theta_rad)
        if self.stated_scale:
            us = self.table.scale_u_at(np.asarray(theta_rad, dtype=float) * ARCSEC_PER_RAD)
            return np.maximum(u**2 - us**2, 0.0)
        return u**2 * self.shares[0]

    def scale_var_at(self, theta_max_rad: float) -> float:
        """Prior variance of the scale error reached at ±``theta_max_rad``, arcsec²: the
        scale share of u(±θ_max)², or the stated scale part there."""
        ends = np.array([-theta_max_rad, theta_max_rad])
        if self.stated_scale:
            return float(np.max(self.table.scale_u_at(ends * ARCSEC_PER_RAD))) ** 2
        return float(np.max(self.u_at(ends))) ** 2 * self.shares[1]

    @property
    def shares(self) -> tuple[float, float]:
        """Fractions of u² given to the per-angle part and to the scale part. Neither a bound
        nor a calibration table states how the errors of different angles correlate: both
        extremes are taken, an independent part and a fully correlated scale part, each
        with the full u² (1, 1) (module docstring). A ``scale_share`` s splits it instead,
        (1 − s, s): constructed cases only."""
        if self.table is not None or self.scale_share is None:  # a stated part: see
            return (1.0, 1.0)  # angle_var_at and scale_var_at
        return (1.0 - self.scale_share, self.scale_share)


def spec_for(
    meta: dict,
    bound_arcsec: float | None,
    source: str = "record",
    *,
    axis: str = "y",
    calibration=None,
    reading: str = "rectangular",
) -> AngleSensorSpec:
    """The knowledge of the ``axis`` sensor: its table in ``calibration`` if it has one;
    else the bound ``bound_arcsec`` if given (CLI), else the header key
    ``platform_angle_bound_{axis}_arcsec``, else ``platform_angle_bound_arcsec``, else the
    paper's 3″ — read as ``reading`` (rectangular by default)."""
    if calibration is not None and calibration.table(axis) is not None:
        return AngleSensorSpec(
            axis=axis,
            calibration=calibration,
            source=f"angle calibration {calibration.id} of {calibration.date}",
        )
    if bound_arcsec is not None:
        return AngleSensorSpec(
            float(bound_arcsec), distribution=reading, axis=axis, source="--angle-bound-arcsec"
        )
    for key in (AXIS_KEYS[axis], HEADER_KEY):
        raw = meta.get(key)
        if raw is None:
            continue
        try:
            value = float(raw)
        except ValueError:
            raise ChekanError(f"{source}: {key}: not a number: {raw!r}") from None
        try:
            return AngleSensorSpec(
                value, distribution=reading, axis=axis, source=f"header {key} of {source}"
            )
        except ChekanError as e:
            raise ChekanError(f"{source}: {key}: {e}") from None
    return AngleSensorSpec(distribution=reading, axis=axis)


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
        """Prior variances of (ζ, ξ), arcsec²: the per-angle part at every commanded angle,
        the scale part at θ_max (:meth:`AngleSensorSpec.angle_var_at`,
        :meth:`AngleSensorSpec.scale_var_at`; a zero bound: a tiny variance keeps the normal
        equations regular)."""
        var = np.concatenate(
            [spec.angle_var_at(self.nodes_rad), [spec.scale_var_at(self.theta_max_rad)]]
        )
        return np.maximum(var, 1e-12)


def slew_error_columns(
    path_theta_rad: np.ndarray, kinds: np.ndarray, on: np.ndarray, n_types: int
) -> np.ndarray:
    """The sensor's error along the slews (H, M, T), one term per slew type t (arcsec):
    ηₜ·sign(θ) on the samples of the slews of that type (:mod:`chekan.joint.slews`).

    What lies between two commanded angles is not known from the sensor's errors there (a
    periodic or graduation error), so the holds' terms are not continued along the slews
    and no shape is assumed. Along a slew the error adds Σₘ wₘ Sₘ e(θₘ) to the lag state
    (Sₘ = ∂E/∂θ, odd in θ); with |e| ≤ U this is at most U·Σₘ wₘ|Sₘ|, reached by
    e = U·sign(θ): the column taken, with the prior of one commanded angle's error
    (:attr:`AngleSensorSpec.per_angle_var`) — the bound's Type B uncertainty of the slew's
    contribution, with no credit for cancellation between its two sides of level.
    """
    hit = type_indicator(kinds, on, n_types)
    return np.where(hit, np.sign(np.asarray(path_theta_rad, dtype=float))[..., None], 0.0)


def sensor_terms(
    theta_rad: np.ndarray,
    on: np.ndarray,
    path_theta_rad: np.ndarray,
    path_on: np.ndarray,
    kinds: np.ndarray,
    n_types: int,
    spec: AngleSensorSpec,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One sensor's systematic terms at the holds (H, A + 1 + T), along the slews
    (H, M, A + 1 + T) and their prior variances: ζ at its A commanded angles (the holds it
    reads, ``on``: :class:`SystematicBasis`), the scale error ξ·θ/θ_max (at those holds and
    along its slews, ``path_on``: linear in θ everywhere), and the slews' own terms, one per
    slew type (``kinds``, :mod:`chekan.joint.slews`; :func:`slew_error_columns`). Shared by
    the estimator (:mod:`chekan.joint.binning`) and the design."""
    theta = np.asarray(theta_rad, dtype=float)
    sb = SystematicBasis.for_holds(theta[on])
    A, H = sb.size - 1, theta.size
    hold = np.concatenate([sb.at(theta) * on[:, None], np.zeros((H, n_types))], axis=1)
    path = np.concatenate(
        [
            np.zeros((*np.shape(path_theta_rad), A)),
            sb.at(path_theta_rad)[..., A:] * path_on[..., None],
            slew_error_columns(path_theta_rad, kinds, path_on, n_types),
        ],
        axis=-1,
    )
    var = np.concatenate([sb.prior_var(spec), np.full(n_types, max(spec.per_angle_var, 1e-12))])
    return hold, path, var


@dataclass(frozen=True)
class SensorReads:
    """What one angle sensor reads in a record: its holds ``on`` (H,), the slew angles
    about its axis (H, M) and the slew samples it reads ``path_on`` (H, M), its slew types
    (``kinds``, ``n_types``: :mod:`chekan.joint.slews`), and what is known of its error."""

    on: np.ndarray
    path_theta_rad: np.ndarray
    path_on: np.ndarray
    kinds: np.ndarray
    n_types: int
    spec: AngleSensorSpec


def all_sensor_terms(
    theta_rad: np.ndarray, sensors: dict[str, SensorReads], path_shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """The systematic terms of every sensor that reads holds, at the holds (H, Q), along
    the slews (H, M, Q) with ``path_shape`` (H, M), their prior variances (Q,), how many are
    common to both sensors and how many are the X sensor's: where both read holds the scale
    error they may share (:func:`common_scale_terms`), then the X sensor's terms, then the
    Y sensor's (:func:`sensor_terms`; a sensor's columns are zero at the other's holds and
    slews). Shared by the estimator (:mod:`chekan.joint.binning`) and the design."""
    theta = np.asarray(theta_rad, dtype=float)
    if not sensors:
        return np.zeros((theta.size, 0)), np.zeros((*path_shape, 0)), np.zeros(0), 0, 0
    holds, paths, variances = [], [], []
    n_x = 0
    for axis in ("x", "y"):
        s = sensors.get(axis)
        if s is None:
            continue
        hold, path, var = sensor_terms(
            theta, s.on, s.path_theta_rad, s.path_on, s.kinds, s.n_types, s.spec
        )
        holds.append(hold)
        paths.append(path)
        variances.append(var)
        n_x = hold.shape[1] if axis == "x" else n_x
    n_common = 0
    if len(sensors) == 2:
        hold, path, var = common_scale_terms(theta, sensors)
        holds.insert(0, hold)
        paths.insert(0, path)
        variances.insert(0, var)
        n_common = 1
    return (
        np.concatenate(holds, axis=1),
        np.concatenate(paths, axis=-1),
        np.concatenate(variances),
        n_common,
        n_x,
    )


def common_scale_terms(
    theta_rad: np.ndarray, sensors: dict[str, SensorReads]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scale error that two angle sensors may share, ξ_c·θ/θ_max at every hold
    (H, 1) and slew sample (H, M, 1) of either sensor, and its prior variance (1,).

    Each sensor's bound says nothing of how its error relates to the
    other's: separate sensors calibrated against one reference may share a scale error, and
    two sensors each at their bound with one sign are admitted. b leans on the sensors with
    weights w and 1 − w; with independent scale terms of u² each (:func:`sensor_terms`)
    and this common one of variance v, the scale part of var(b) is (w² + (1 − w)²)u² + v
    (in units of b's sensitivity). v = u²/2 is the smallest common term for which that is
    never below u², so that two sensors at their bound together are covered as one sensor
    at its bound is (the module docstring's 2/√3 > 1); u is the smaller sensor's (a common
    fractional scale s reaches at most min_s U_s/θ_max,s). Without it, such pairs moved b
    by up to 2.5 of its sd (the validation at the edge of the specification,
    ``docs/figures/validation_dual.md``)."""
    theta = np.asarray(theta_rad, dtype=float)
    t_max = {a: max(float(np.max(np.abs(theta[s.on]))), 1e-9) for a, s in sensors.items()}
    t_all = max(t_max.values())
    hold = np.zeros((theta.size, 1))
    path = None
    var = []
    for a, s in sensors.items():
        hold[:, 0] += np.where(s.on, theta, 0.0) / t_all
        along = np.where(s.path_on, np.asarray(s.path_theta_rad, dtype=float), 0.0) / t_all
        path = along if path is None else path + along
        var.append(s.spec.scale_var_at(t_max[a]) * (t_all / t_max[a]) ** 2)
    return hold, np.asarray(path)[..., None], np.array([max(min(var) / 2.0, 1e-12)])


def systematic_basis(theta_rad: np.ndarray, spec: AngleSensorSpec) -> tuple[np.ndarray, np.ndarray]:
    """The systematic angle-error basis at the holds (H, A + 1) and its prior variances:
    one column per commanded angle (an indicator at the holds), then θₖ/θ_max."""
    basis = SystematicBasis.for_holds(theta_rad)
    return basis.at(theta_rad), basis.prior_var(spec)
