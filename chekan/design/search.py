"""Search for a tilt program with a smaller expected sd within a clock-time budget.

**Search** (:func:`search_programs`): candidates described by a :class:`ProgramSpec`
(number of distinct angles, their spacing, the lowest angle, the order scheme, rounds,
settle time) inside the paper's range ±1°50′…±5°10′, each given the longest dwell
(whole seconds, at least ``min_dwell_s``) that fits the budget; a coarse grid over
(angles, rounds, settle) followed by a coordinate search (every coordinate in turn
over all its values, best first, until no coordinate improves) from the three best grid
points. The given program is always a candidate, so the result is never worse than it
in what a certificate states: the best is the smallest expected U = k·sd
(:func:`assess`, :mod:`chekan.design.reliability`), not the smallest sd.

**Systematic angle errors** (:mod:`chekan.joint.angles`; ``DesignValues.angle_bound_arcsec``,
default 3″): one ζ per commanded signed angle and a scale ξ per axis sensor, shared by
all rounds. They do not average over rounds, so the hold count alone no longer decides:
distinct angles (each brings its own ζ), ± pairs (two ζ at each |θ|), large angles (the
same ″ is a smaller part of θ; the scale term sets δb/b = 2ξ/θ_max) and tilts about X,
read by the other sensor, whose errors are independent, help. The numbers for the
paper's clock (``chekan design --search``, 9.16 h with slews; sd of b₁, ppm, at the
design values; bound 3″ / 0):

=========================================================  ===========  ==========
program                                                    3″           0
=========================================================  ===========  ==========
the paper's (8 angles, 2 rounds about Y, 900 s)            337.8        279.9
best at 3″, about Y only: 6 angles θ-spaced 1°50′…5°10′,   185.6        117.7
zigzag, 12 rounds, dwell 181 s, settle 120 s
best at 0 about Y only: 3 angles 3°10′…5°10′, 20 rounds    198.1        104.9
best at 3″: 3 angles 4°30′, 4°51′, 5°10′, alternate,       80.0         44.3
20 rounds alternating Y and X, dwell 188 s, settle 120 s
(b₂ 82.3 / 45.9; the paper's b₂ 346.6 / 287.2; with the X response's nuisance)
=========================================================  ===========  ==========

About Y only, the systematic errors call for more distinct angles (6 rather than 3).
With X tilts the model's gain is large (b₂ alike): the X rounds are read by the other
angle sensor, whose errors are independent, and under tilts about X the pendulum's
stiffness changes by g·θ/(bK), which ties K to the response. What eq. (6) may lack about X
is a nuisance here as in the estimator (:mod:`chekan.joint.xresponse`); the simulated
check is in ``docs/figures/validation_dual.md``.

"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from chekan.design.information import OBJECTIVES, ExpectedPrecision, expected_precision
from chekan.design.layout import DesignValues, program_clock_s
from chekan.design.reliability import ExpectedReliability, expected_reliability
from chekan.errors import ChekanError
from chekan.physics.program import TiltProgram, build_program
from chekan.physics.units import format_dms
from inference.dof import coverage_factor

LOWEST_ANGLE_ARCMIN = 110  # 1°50′: the paper's smallest tilt
HIGHEST_ANGLE_ARCMIN = 310  # 5°10′: the paper's largest tilt
MIN_DWELL_S = 180.0  # search default: shortest dwell of a candidate
MIN_SETTLE_S = 120.0  # search default: 4τ; the lag is modelled, but only as first order
MIN_SETTLED_S = 60.0  # dwell − settle: samples after settling in every hold
SCHEMES = {  # name → (order, sequence); "interleaved": as-given, largest/smallest alternating
    "paper": ("+-", "ascending"),
    "alternate": ("alternate", "ascending"),
    "zigzag": ("alternate", "zigzag"),
    "descending": ("+-", "descending"),
    "interleaved": ("+-", "as-given"),
}


@dataclass(frozen=True)
class ProgramSpec:
    """A candidate program, described by the coordinates the search moves along.

    Angles: ``n_angles`` magnitudes from ``lowest_arcmin`` to 5°10′, equally spaced in
    Δg ∝ 1 − cos θ (``spacing="dg"``, the paper's rule: "Δg grows by about 500 mGal from one
    angle to the next") or in θ (``"angle"``), rounded to whole arcminutes. ``scheme``: the
    order of the holds (:data:`SCHEMES`): "paper" (+θ, −θ pairs ascending), "alternate"
    (+− in odd rounds, −+ in even), "zigzag" (alternate, and ascending/descending by
    round), "descending", "interleaved" (largest, smallest, second largest, … : angle
    uncorrelated with time). ``axis``: "y", "x", or "xy" (rounds alternate Y and X: the
    two axes are read by different angle sensors, whose systematic errors are independent).
    The dwell is not a coordinate: it is the longest (whole
    seconds) that fits the budget.
    """

    n_angles: int = 8
    spacing: str = "dg"
    lowest_arcmin: int = LOWEST_ANGLE_ARCMIN
    scheme: str = "paper"
    rounds: int = 2
    settle_s: float = 300.0
    axis: str = "y"

    def label(self) -> str:
        axis = "Y and X alternating" if self.axis == "xy" else self.axis.upper()
        return (
            f"{self.n_angles} angles ({self.spacing}, from {format_dms(self.lowest_arcmin / 60)}), "
            f"{self.scheme}, {self.rounds} round(s) about {axis}, settle {self.settle_s:g} s"
        )


SEARCH_SPACE: dict[str, tuple] = {
    "n_angles": (2, 3, 4, 5, 6, 8, 10, 12, 16),
    "spacing": ("dg", "angle"),
    "lowest_arcmin": (110, 150, 190, 230, 270),
    "scheme": tuple(SCHEMES),
    "rounds": (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24),
    "settle_s": (60.0, 90.0, 120.0, 180.0, 240.0, 300.0),
    "axis": ("y", "x", "xy"),
}


def spec_angles_arcmin(spec: ProgramSpec) -> list[int]:
    """The distinct tilt magnitudes of a spec in whole arcminutes, ascending (may be fewer
    than ``n_angles`` when rounding merges two)."""
    lo, hi = spec.lowest_arcmin, HIGHEST_ANGLE_ARCMIN
    if spec.n_angles == 1 or lo >= hi:
        return [hi]
    if spec.spacing == "dg":
        x = np.linspace(
            1 - math.cos(math.radians(lo / 60)), 1 - math.cos(math.radians(hi / 60)), spec.n_angles
        )
        theta_arcmin = np.degrees(np.arccos(1 - x)) * 60
    elif spec.spacing == "angle":
        theta_arcmin = np.linspace(lo, hi, spec.n_angles)
    else:
        raise ValueError(f"unknown spacing {spec.spacing!r}")
    return sorted({round(float(a)) for a in theta_arcmin})


def _interleave(values: list) -> list:
    """largest, smallest, second largest, second smallest, …"""
    out, lo, hi = [], 0, len(values) - 1
    while lo <= hi:
        out.append(values[hi])
        if lo != hi:
            out.append(values[lo])
        lo, hi = lo + 1, hi - 1
    return out


def program_within_budget(
    angles_deg,
    budget_s: float,
    *,
    settle_s: float,
    rounds: int,
    order: str = "+-",
    sequence: str = "ascending",
    axis: str = "y",
    name: str | None = None,
    values: DesignValues | None = None,
    min_dwell_s: float = MIN_DWELL_S,
) -> TiltProgram | None:
    """The program with these angles and order and the longest dwell (whole seconds) whose
    clock time with slews fits ``budget_s``: dwell = ⌊(budget − slews)/steps⌋. None when
    that dwell is below ``min_dwell_s`` or leaves less than ``MIN_SETTLED_S`` after
    ``settle_s``."""
    kw: dict = dict(axis=axis, order=order, sequence=sequence, rounds=rounds)
    probe = build_program(angles_deg, dwell_s=1.0, settle_s=0.0, **kw)
    slew_s = program_clock_s(probe, values) - probe.duration_s  # moves do not depend on dwell
    dwell = float(math.floor((budget_s - slew_s) / probe.n_steps))
    if dwell < min_dwell_s or dwell - settle_s < MIN_SETTLED_S:
        return None
    name = name or f"design-{len(probe.angles_rad)}x{rounds}-{dwell:g}s"
    return build_program(angles_deg, name=name, dwell_s=dwell, settle_s=settle_s, **kw)


def spec_program(
    spec: ProgramSpec,
    budget_s: float,
    *,
    axis: str | None = None,
    values: DesignValues | None = None,
    min_dwell_s: float = MIN_DWELL_S,
) -> TiltProgram | None:
    """The program of a spec (:func:`program_within_budget`) about ``axis`` (default: the
    spec's); None when rounding to whole arcminutes merged two angles or the dwell does
    not fit."""
    angles = spec_angles_arcmin(spec)
    if len(angles) < spec.n_angles:
        return None
    order, sequence = SCHEMES[spec.scheme]
    if spec.scheme == "interleaved":
        angles = _interleave(angles)
    return program_within_budget(
        [a // 60 + (a % 60) / 60.0 for a in angles],  # as a program file's DMS reads back
        budget_s,
        settle_s=spec.settle_s,
        rounds=spec.rounds,
        order=order,
        sequence=sequence,
        axis=axis or spec.axis,
        values=values,
        min_dwell_s=min_dwell_s,
    )


@dataclass(frozen=True)
class Candidate:
    """One evaluated program: its spec (None for the given program), precision, and (for
    the programs a search assesses) the expected ν_eff and k of its uncertainty."""

    spec: ProgramSpec | None
    precision: ExpectedPrecision
    objective: float
    reliability: ExpectedReliability | None = None
    objective_name: str = "b_mean"

    @property
    def program(self) -> TiltProgram:
        return self.precision.program

    @property
    def expected_u(self) -> float | None:
        """The objective's expected expanded uncertainty k·sd (inf where ν_eff < 1; None
        when not assessed)."""
        if self.reliability is None:
            return None
        return self.objective * self.reliability.k_of(self.objective_name)


def within(c: Candidate, budget_s: float) -> bool:
    """Whether a candidate's clock time fits ``budget_s`` (to a microsecond)."""
    return c.precision.clock_s <= budget_s + 1e-6


@dataclass(frozen=True)
class SearchResult:
    """Candidates ranked by the objective (best first); ``given`` is the input program,
    ranked with the rest for comparison even when it does not fit a smaller budget."""

    given: Candidate
    ranked: list[Candidate]
    objective: str
    budget_s: float
    evaluations: int
    seconds: float

    def fits(self, c: Candidate) -> bool:
        return within(c, self.budget_s)

    @property
    def best(self) -> Candidate:
        """The candidate within the budget with the smallest expected expanded uncertainty
        k·sd (:func:`assess`: the sd alone where none was assessed; ChekanError when none
        fits)."""
        fit = [c for c in self.ranked if self.fits(c)]
        if not fit:
            raise ChekanError(
                f"no program fits {self.budget_s / 3600:.2f} h with dwells ≥ the minimum; "
                "raise --budget-h or lower --min-dwell-s/--min-settle-s"
            )
        scored = [(u, i) for i, c in enumerate(fit) if (u := c.expected_u) is not None]
        return fit[min(scored)[1]] if scored else fit[0]  # ties: the smaller sd


def assess(
    ranked: list[Candidate],
    fits: Callable[[Candidate], bool],
    values: DesignValues,
    top: int,
) -> list[Candidate]:
    """``ranked`` (by sd) with the expected ν_eff and k (:mod:`chekan.design.reliability`) of
    the first ``top``, of the given program, and of every candidate within the budget that
    could still have the smallest k·sd: k ≥ k(∞) = 2, so one whose 2·sd exceeds the smallest
    k·sd found cannot, and the rest are not assessed (a program that cannot estimate its own
    noise has a small sd and a large k, or none)."""
    k_min = coverage_factor(math.inf)
    out = list(ranked)
    best_u = math.inf
    for i, c in enumerate(out):
        contender = fits(c) and k_min * c.objective < best_u
        if i >= top and c.spec is not None and not contender:
            continue
        c = out[i] = replace(c, reliability=expected_reliability(c.program, values))
        if fits(c) and c.expected_u is not None:
            best_u = min(best_u, c.expected_u)
    return out


def _spec_key(spec: ProgramSpec) -> tuple:
    return tuple(getattr(spec, k) for k in SEARCH_SPACE)


def search_programs(
    program: TiltProgram,
    *,
    budget_s: float | None = None,
    objective: str = "b_mean",
    values: DesignValues | None = None,
    space: dict[str, tuple] | None = None,
    min_dwell_s: float = MIN_DWELL_S,
    min_settle_s: float = MIN_SETTLE_S,
    start_points: int = 3,
    max_sweeps: int = 4,
    top: int = 15,
) -> SearchResult:
    """Search for a program with a smaller expected sd within a clock-time budget.

    1. the given program (always a candidate: the result is never worse);
    2. a grid over (``n_angles``, ``rounds``, ``settle_s``, ``axis``) with the other
       coordinates at the paper's choices (Δg spacing from 1°50′, paper order);
    3. coordinate search from the ``start_points`` best grid points: each coordinate of
       ``space`` in turn is set to every one of its values, the best is kept, until a
       sweep improves nothing (at most ``max_sweeps``).

    Every candidate gets the longest dwell that fits ``budget_s`` (default: the given
    program's clock time, :func:`program_clock_s`), at least ``min_dwell_s``, with a settle
    time of at least ``min_settle_s``. Under the estimator's model every hold brings an
    independent offset and angle error, so the sd falls roughly as 1/√(number of holds)
    and the search runs to the shortest dwell allowed: the two limits are where the
    engineering judgement goes (how far the first-order lag can be trusted).

    4. :func:`assess`: the expected ν_eff and k of the ``top`` best (the table's rows), of
       the given program and of every contender; :attr:`SearchResult.best` is the one
       with the smallest expected k·sd, what a certificate would state as U.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; choose one of {', '.join(OBJECTIVES)}")
    values = values or DesignValues()
    space = dict(space or SEARCH_SPACE)
    space["settle_s"] = tuple(
        sorted({float(min_settle_s)} | {float(x) for x in space["settle_s"] if x >= min_settle_s})
    )
    t0 = time.perf_counter()
    budget = float(budget_s) if budget_s is not None else program_clock_s(program, values)
    given_prec = expected_precision(program, values)
    given = Candidate(None, given_prec, given_prec.objective(objective), None, objective)
    seen: dict[tuple, Candidate | None] = {}

    def evaluate(spec: ProgramSpec) -> Candidate | None:
        key = _spec_key(spec)
        if key not in seen:
            prog = spec_program(spec, budget, values=values, min_dwell_s=min_dwell_s)
            if prog is None:
                seen[key] = None
            else:
                prec = expected_precision(prog, values)
                seen[key] = Candidate(spec, prec, prec.objective(objective), None, objective)
        return seen[key]

    base = ProgramSpec(settle_s=space["settle_s"][-1], axis=program.axis)
    grid = [
        replace(base, n_angles=n, rounds=r, settle_s=st, axis=ax)
        for n in space["n_angles"]
        for r in space["rounds"]
        for st in space["settle_s"]
        for ax in space.get("axis", (program.axis,))
    ]
    scored = sorted((c for c in map(evaluate, grid) if c is not None), key=lambda c: c.objective)
    for current in scored[:start_points]:
        for _ in range(max_sweeps):
            improved = False
            for name, options in space.items():
                for opt in options:
                    assert current.spec is not None  # grid points all have one
                    c = evaluate(replace(current.spec, **{name: opt}))
                    if c is not None and c.objective < current.objective * (1 - 1e-9):
                        current, improved = c, True
            if not improved:
                break
    evaluated = [c for c in seen.values() if c is not None]
    ranked = sorted([given, *evaluated], key=lambda c: c.objective)
    ranked = assess(ranked, lambda c: within(c, budget), values, top)
    return SearchResult(
        given=next(c for c in ranked if c.spec is None),
        ranked=ranked,
        objective=objective,
        budget_s=budget,
        evaluations=1 + len(evaluated),
        seconds=time.perf_counter() - t0,
    )
