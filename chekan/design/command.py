"""``chekan design``: the expected precision of a program, the search, and their output
(text tables, a TOML program file, the ``chekan-design/1`` JSON)."""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from chekan.design.information import (
    ExpectedPrecision,
    expected_precision,
    settled_tau_limit_s,
    settled_transient_pix,
)
from chekan.design.layout import DesignValues, program_clock_s
from chekan.design.reliability import ExpectedReliability, expected_reliability
from chekan.design.search import Candidate, SearchResult, search_programs
from chekan.errors import ChekanError
from chekan.files.durable import atomic_output
from chekan.joint.xresponse import horizontal_prior
from chekan.physics.program import TiltProgram
from chekan.physics.units import format_dms, parse_angle_deg

#: The largest bound of an angle sensor's error that a design takes, arcsec (1°).
MAX_BOUND_ARCSEC = 3600.0


def format_precision(
    prec: ExpectedPrecision,
    random_only: ExpectedPrecision | None = None,
    reliability: ExpectedReliability | None = None,
) -> str:
    """The expected sds of b₁, b₂ (at the level reading and at the CCD centre) and a; with
    ``random_only`` (the same program without systematic angle errors) also the share of
    the sensors' systematic error, in quadrature; with ``reliability`` the expected ν_eff,
    k and U."""
    p = prec.program
    lines = [
        f"{p.describe()}",
        f"clock time with slews {prec.clock_s / 3600:.2f} h; {prec.n_holds} holds, "
        f"{prec.n_bins} bins per system",
        "expected posterior sd (Laplace, at the design values):",
    ]
    for name, what in (
        ("b1", "b1 (level reading)"),
        ("b2", "b2 (level reading)"),
        ("b1_0", "b1 at the CCD centre"),
        ("b2_0", "b2 at the CCD centre"),
    ):
        lines.append(
            f"  {what:<22} {prec.sd[name]:.3e} mGal/pix   ({prec.sd_ppm(name):6.1f} ppm of "
            f"{prec.value[name]:.4f})"
        )
    lines.append(
        f"  {'a':<22} {prec.sd['a']:.3e} mGal/pix^2 ({prec.sd_ppm('a'):6.0f} ppm of "
        f"{prec.value['a']:.4e})"
    )
    if random_only is not None:
        parts = []
        for name in ("b1", "b2"):
            sys2 = max(prec.sd[name] ** 2 - random_only.sd[name] ** 2, 0.0)
            parts.append(
                f"{name} {random_only.sd_ppm(name):.1f} ppm random + "
                f"{1e6 * math.sqrt(sys2) / abs(prec.value[name]):.1f} ppm systematic"
            )
        lines.append("  of which (in quadrature): " + "; ".join(parts))
    lines.append(
        f"  also: tau {prec.sd['tau_s']:.2g} s, eps1 {prec.sd['eps1_arcmin']:.2g}', "
        f"eps2 {prec.sd['eps2_arcmin']:.2g}', dgamma {prec.sd['dgamma_arcmin']:.2g}'"
    )
    if reliability is not None:
        lines.extend(format_reliability(prec, reliability))
    return "\n".join(lines)


def nu_text(nu: float) -> str:
    """ν_eff as a table shows it: "< 1" below one degree of freedom (no finite k)."""
    return "< 1" if nu < 1.0 else f"{nu:.0f}" if nu < 1e5 else "> 1e5"


def format_reliability(prec: ExpectedPrecision, rel: ExpectedReliability) -> list[str]:
    """The expected ν_eff and k of b₁, b₂, a and the expanded uncertainty U = k·sd they give
    (:mod:`chekan.design.reliability`), with a warning where the record could not estimate
    its own noise."""
    parts = []
    for name in ("b1", "b2", "a"):
        k = rel.k[name]
        u = "no U" if math.isinf(k) else f"U {k * prec.sd_ppm(name):.0f} ppm"
        parts.append(f"{name} {nu_text(rel.nu_eff[name])} (k {k:.2f}, {u})")
    lines = ["  expected nu_eff (the noise estimated from the record): " + "; ".join(parts)]
    worst = min(rel.nu_eff[n] for n in ("b1", "b2", "a"))
    if worst < 1.0:
        lines.append(
            "  warning: the record cannot estimate its own noise (nu_eff < 1): a certificate "
            "of it states no expanded uncertainty; hold each angle more than once"
        )
    elif rel.k_of("b_max") > 2.5 or rel.k["a"] > 2.5:
        lines.append(
            "  warning: few effective degrees of freedom: the coverage factor k is well above 2"
        )
    if rel.clipped:
        lines.append("  (the noise components' expected information was indefinite)")
    return lines


def candidate_row(c: Candidate) -> dict:
    """One row of the ranked table (plain numbers, JSON-ready)."""
    p, prec = c.program, c.precision
    return {
        "name": p.name,
        "given": c.spec is None,
        "angles": [format_dms(math.degrees(a)) for a in p.angles_rad],
        "n_angles": len(p.angles_rad),
        "axis": p.axis,
        "order": p.order,
        "sequence": p.sequence,
        "rounds": p.rounds,
        "dwell_s": p.dwell_s,
        "settle_s": p.settle_s,
        "n_steps": p.n_steps,
        "clock_h": prec.clock_s / 3600.0,
        "sd_b1_mgal_per_pix": prec.sd["b1"],
        "sd_b2_mgal_per_pix": prec.sd["b2"],
        "sd_a_mgal_per_pix2": prec.sd["a"],
        "sd_b1_ppm": prec.sd_ppm("b1"),
        "sd_b2_ppm": prec.sd_ppm("b2"),
        "objective": c.objective,
        "expected_nu_eff": None if c.reliability is None else dict(c.reliability.nu_eff),
        "expected_k": None if c.reliability is None else _finite_or_none(c.reliability.k),
        "expected_u_objective": _finite(c.expected_u),
    }


def _finite(x: float | None) -> float | None:
    """JSON has no infinity: an infinite (or absent) figure is null."""
    return None if x is None or not math.isfinite(x) else x


def _finite_or_none(d: dict[str, float]) -> dict[str, float | None]:
    return {k: _finite(v) for k, v in d.items()}


def format_table(result: SearchResult, top: int = 15) -> str:
    """Ranked table of the best ``top`` candidates (and the given program wherever it is)."""
    cols = (
        ("#", 3),
        ("angles", -18),
        ("spacing", -7),
        ("axis", -4),
        ("order", -9),
        ("sequence", -10),
        ("rounds", 6),
        ("dwell", 6),
        ("settle", 6),
        ("steps", 5),
        ("clock h", 7),
        ("sd b1 ppm", 9),
        ("sd b2 ppm", 9),
        ("sd a", 9),
        ("nu_eff", 6),
        ("k", 5),
    )

    def line(cells) -> str:
        pairs = zip(cells, (w for _, w in cols), strict=True)
        return " ".join(f"{c:<{-w}}" if w < 0 else f"{c:>{w}}" for c, w in pairs)

    lines = [line([name for name, _ in cols])]
    try:
        best: Candidate | None = result.best
    except ChekanError:
        best = None
    for i, c in enumerate(result.ranked):
        if i >= top and c is not result.given:
            continue
        r = candidate_row(c)
        lo, hi = min(r["angles"], key=_dms_key), max(r["angles"], key=_dms_key)
        spacing = {"dg": "Δg", "angle": "θ"}[c.spec.spacing] if c.spec else "given"
        cells = (
            i + 1,
            f"{r['n_angles']} {lo}..{hi}",
            spacing,
            r["axis"],
            r["order"],
            r["sequence"],
            r["rounds"],
            f"{r['dwell_s']:g}",
            f"{r['settle_s']:g}",
            r["n_steps"],
            f"{r['clock_h']:.2f}",
            f"{r['sd_b1_ppm']:.1f}",
            f"{r['sd_b2_ppm']:.1f}",
            f"{r['sd_a_mgal_per_pix2']:.2e}",
            "—" if c.reliability is None else nu_text(c.reliability.nu_of(result.objective)),
            _k_text(c, result.objective),
        )
        note = "  <- given" if r["given"] else ""
        if c is best and not r["given"]:
            note += "  <- best"
        if r["given"] and not result.fits(c):
            note += " (over the budget)"
        lines.append(line(cells) + note)
    return "\n".join(lines)


def _dms_key(text: str) -> float:
    from chekan.physics.units import parse_angle_deg

    return parse_angle_deg(text)


def program_toml(program: TiltProgram) -> str:
    """A TOML program file that :func:`chekan.physics.program.load_program` reads back to the same
    program, step for step (angles in whole arcminutes as DMS text where that reads back to
    the same number, otherwise as decimal degrees; the axis, or the axis of each round)."""

    def angle_text(deg: float) -> str:
        arcmin = deg * 60.0
        if abs(arcmin - round(arcmin)) < 1e-9 and parse_angle_deg(format_dms(deg)) == deg:
            return json.dumps(format_dms(deg), ensure_ascii=False)
        return json.dumps(repr(deg))

    degs = program.angles_deg or tuple(math.degrees(a) for a in program.angles_rad)
    angles = ", ".join(angle_text(a) for a in degs)
    axis_line = (
        f"round_axes = {json.dumps(list(program.round_axes))}\n"
        if program.axes_given
        else f"axis = {json.dumps(program.axis)}\n"
    )
    return (
        f"# written by chekan design ({program_clock_s(program) / 3600:.2f} h with slews)\n"
        f"name = {json.dumps(program.name, ensure_ascii=False)}\n"
        f"angles = [{angles}]\n" + axis_line + f"order = {json.dumps(program.order)}\n"
        f"sequence = {json.dumps(program.sequence)}\n"
        f"dwell_s = {_number(program.dwell_s)}\n"
        f"settle_s = {_number(program.settle_s)}\n"
        f"rounds = {program.rounds}\n"
    )


def _number(x: float) -> str:
    """``x`` as TOML text that reads back to the same float (short where exact)."""
    short = f"{x:g}"
    return short if float(short) == x else repr(float(x))


def write_program_toml(path: str | Path, program: TiltProgram) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as f:
        f.write(program_toml(program))
    return path


def precision_json(prec: ExpectedPrecision) -> dict:
    return {
        "program": prec.program.describe(),
        "clock_h": prec.clock_s / 3600.0,
        "n_holds": prec.n_holds,
        "sd": dict(prec.sd),
        "value": dict(prec.value),
        "sd_ppm": {k: prec.sd_ppm(k) for k in ("b1", "b2", "b1_0", "b2_0", "a")},
    }


def reliability_json(rel: ExpectedReliability) -> dict:
    """The expected ν_eff and k (null where infinite) of a program."""
    return {
        "nu_eff": dict(rel.nu_eff),
        "k": _finite_or_none(rel.k),
        "components": list(rel.components),
        "clipped": rel.clipped,
    }


def design_json(
    prec: ExpectedPrecision,
    result: SearchResult | None,
    values: DesignValues,
    reliability: ExpectedReliability | None = None,
) -> dict:
    """Everything ``chekan design --json`` writes."""
    t = values.truth
    given = precision_json(prec)
    if reliability is not None:
        given["expected"] = reliability_json(reliability)
    out: dict = {
        "format": "chekan-design/1",
        "assumptions": {
            "noise_pix_per_sample": list(t.noise_pix),
            "hold_offset_sd_pix": t.hold_offset_sd_pix,
            "angle_error_sd_arcsec": t.angle_error_sd_arcsec,
            "tau_s": t.tau_s,
            "slew_error": values.slew_error,
            "drift_degree": values.drift_degree,
            "slew_deg_per_s": t.slew_deg_per_s,
            "angle_bound_arcsec": values.angle_bound_arcsec,
            "angle_scale_share": values.angle_scale_share,
            "angle_calibration": (
                None if values.angle_calibration is None else values.angle_calibration.entry()
            ),
            "horizontal_u_pix": horizontal_prior(values.horizontal_u_pix)[0],
        },
        "given": given,
    }
    if result is not None:
        out["search"] = {
            "objective": result.objective,
            "budget_h": result.budget_s / 3600.0,
            "evaluations": result.evaluations,
            "seconds": result.seconds,
            "best": precision_json(result.best.precision)
            | (
                {}
                if result.best.reliability is None
                else {"expected": reliability_json(result.best.reliability)}
            ),
            "best_toml": program_toml(result.best.program),
            "ranked": [candidate_row(c) for c in result.ranked],
            "best_index": result.ranked.index(result.best),
        }
    return out


def classical_settling(program: TiltProgram, values: DesignValues) -> dict:
    """What the program's settling leaves of the slews' transients in the hold means that
    the classical method (Calibr.exe) averages: the largest, pix, at the design τ, and the
    longest τ that keeps it within :data:`chekan.classical.settling.UNSETTLED_PIX`."""
    return {
        "settle_s": program.settle_s,
        "tau_s": values.truth.tau_s,
        "transient_pix": settled_transient_pix(program, values),
        "tau_limit_s": settled_tau_limit_s(program, values),
    }


def settling_text(s: dict) -> str:
    """One line for :func:`classical_settling`."""
    from chekan.classical.settling import UNSETTLED_PIX

    lim = s["tau_limit_s"]
    span = (
        f"within {UNSETTLED_PIX:g} pix for τ ≤ {lim:.0f} s only" if lim < 1000.0
        else f"within {UNSETTLED_PIX:g} pix for any τ up to 1000 s"
    )  # fmt: skip
    biased = s["transient_pix"] > UNSETTLED_PIX
    return (
        f"classical items (--method classical, as Calibr.exe): the {s['settle_s']:g} s settling "
        f"leaves up to {s['transient_pix']:.2g} pix of a slew's transient in a hold mean at "
        f"τ = {s['tau_s']:g} s, {span}"
        + (
            "; they are biased by it where map and bayes remove it (README, «Unsettled hold means»)"
            if biased
            else ""
        )
    )


def _k_text(c: Candidate, objective: str) -> str:
    """A candidate's expected k for an objective, "—" where it was not assessed."""
    return "—" if c.reliability is None else f"{c.reliability.k_of(objective):.2f}"


def design_values(args, program: TiltProgram) -> DesignValues:
    """The design values that ``--angle-bound-arcsec`` or ``--angle-calibration`` ask for;
    a bad bound, a table that cannot be read or does not cover the angles the design
    evaluates (the program's, and with ``--search`` the search's ±1°50′…±5°10′ about each
    axis the table has), or both options at once: an error before any work."""
    bound = getattr(args, "angle_bound_arcsec", None)
    cal_path = getattr(args, "angle_calibration", None)
    if bound is not None and cal_path is not None:
        raise ChekanError(
            "give --angle-bound-arcsec or --angle-calibration, not both: a calibration table "
            "replaces the bound for the axes it has"
        )
    if bound is not None and not 0.0 <= bound <= MAX_BOUND_ARCSEC:
        raise ChekanError(
            f"--angle-bound-arcsec {bound:g}: the bound of an angle sensor's error must lie in "
            f"[0, {MAX_BOUND_ARCSEC:g}] arcsec"
        )
    if cal_path is not None:
        from chekan.records.anglecal import read_angle_calibration

        cal = read_angle_calibration(cal_path)
        _check_covered(cal, program, search=bool(args.search or args.out))
        values = DesignValues(angle_calibration=cal)
    else:
        values = DesignValues() if bound is None else DesignValues(angle_bound_arcsec=float(bound))
    _ = values.angle_spec  # a bad bound is an error before any work
    u = getattr(args, "horizontal_u_pix", None)
    return values if u is None else replace(values, horizontal_u_pix=float(u))


def _check_covered(cal, program: TiltProgram, search: bool) -> None:
    """Refuse a table that does not cover the angles the design evaluates about its axes
    (nothing is extrapolated, as in :func:`chekan.records.anglecal.corrected`)."""
    from chekan.design.search import HIGHEST_ANGLE_ARCMIN
    from chekan.physics.units import ARCSEC_PER_RAD

    for axis, table in sorted(cal.tables.items()):
        theta = [s.theta_rad * ARCSEC_PER_RAD for s in program.steps if s.axis == axis]
        what = f"the program's angles about {axis.upper()}"
        if search:
            theta += [-60.0 * HIGHEST_ANGLE_ARCMIN, 60.0 * HIGHEST_ANGLE_ARCMIN]
            top = format_dms(HIGHEST_ANGLE_ARCMIN / 60.0, sign="pm")
            what = f"the search's angles about {axis.upper()} (up to {top})"
        if not theta:
            continue
        out = ~table.covers(np.asarray(theta, dtype=float))
        if out.any():
            lo, hi = table.span_arcsec
            worst = max(np.asarray(theta)[out], key=abs)
            raise ChekanError(
                f"{cal.path}: axis {axis} covers {lo:g}…{hi:g}″, but {what} reach {worst:g}″: "
                "nothing is extrapolated"
            )


def angle_sensors_text(values: DesignValues) -> str:
    """What the design assumes of the angle sensors, in words."""
    cal = values.angle_calibration
    bound = (
        f"systematic error bound {values.angle_bound_arcsec:g}″ per axis, per commanded "
        "angle and scale; --angle-bound-arcsec 0 leaves it out"
    )
    if cal is None:
        return bound
    parts = []
    for axis in ("y", "x"):
        table = cal.table(axis)
        if table is None:
            parts.append(
                f"{axis.upper()}: no table, the bound {values.angle_bound_arcsec:g}″ here, but "
                f"chekan calibrate refuses a record tilted about {axis.upper()} with this table"
            )
        else:
            scale = (
                ""
                if table.scale_U_arcsec is None
                else f", of it a scale error {table.scale_U_arcsec:g}″ (stated)"
            )
            parts.append(
                f"{axis.upper()}: its table, U ≤ {float(np.max(table.U_arcsec)):g}″ (k = 2)" + scale
            )
    return f"the platform's angle calibration {cal.id} of {cal.date} ({'; '.join(parts)})"


def horizontal_text(values: DesignValues) -> str:
    """What the design assumes of the pendulums' horizontal, in words."""
    u, why = horizontal_prior(values.horizontal_u_pix)
    return f"the CCD centre, standard uncertainty {u:g} pix ({why})"


def run_design_command(args) -> int:
    """``chekan design [PROGRAM.toml] [--budget-h H] [--search] [--out best.toml] [--json J]``."""
    from chekan.physics.program import default_program, load_program

    program = load_program(args.program) if args.program else default_program()
    values = design_values(args, program)
    no_sys = values.without_systematic()
    t0 = time.perf_counter()
    prec = expected_precision(program, values)
    print(f"given program ({args.program or 'the paper’s default'}):")
    print(
        "(programs with rounds about X, axis x or xy: the joint model (--method map, bayes) "
        "calibrates all rounds, with the X rounds' response beyond eq. (6) as a nuisance; "
        "the classical method certifies the rounds about Y and reports those about X beside them)"
    )
    if values.systematic:
        print(f"(angle sensors: {angle_sensors_text(values)})")
    if any(s.axis == "x" for s in program.steps):
        print(f"(the pendulums' horizontal: {horizontal_text(values)})")
    rnd = expected_precision(program, no_sys) if values.systematic else None
    rel = expected_reliability(program, values)
    print(format_precision(prec, rnd, rel))
    settling = classical_settling(program, values)
    print(settling_text(settling))
    print(
        f"(design model evaluated in {1e3 * (time.perf_counter() - t0):.0f} ms, first call "
        "includes the one-off JAX grid)"
    )
    result = None
    if args.search or args.out:
        budget_s = args.budget_h * 3600.0 if args.budget_h else None
        result = search_programs(
            program,
            budget_s=budget_s,
            objective=args.objective,
            values=values,
            min_dwell_s=args.min_dwell_s,
            min_settle_s=args.min_settle_s,
            top=args.top,
        )
        print(
            f"\nsearch: {result.evaluations} programs within {result.budget_s / 3600:.2f} h "
            f"(clock time with slews), objective {result.objective}, "
            f"{result.seconds:.1f} s ({1e3 * result.seconds / result.evaluations:.0f} ms each)"
        )
        print(format_table(result, top=args.top))
        best = result.best
        if best.spec is None:
            print("\nthe given program is the best found")
        else:
            gain = result.given.objective / best.objective
            print(f"\nbest: {best.spec.label()}, dwell {best.program.dwell_s:g} s")
            rnd = expected_precision(best.program, no_sys) if values.systematic else None
            print(format_precision(best.precision, rnd, best.reliability))
            print(settling_text(classical_settling(best.program, values)))
            print(f"objective {result.objective}: {gain:.2f}× smaller sd than the given program")
            if best is not result.ranked[0]:
                print(
                    f"(chosen by the expected U = k·sd: #1 has the smaller sd, k "
                    f"{_k_text(result.ranked[0], result.objective)})"
                )
        if args.out:
            written = write_program_toml(args.out, best.program)
            print(f"wrote {written} (best program; chekan program {written} shows it)")
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path) as f:
            doc = design_json(prec, result, values, rel)
            doc["given"]["classical_settling"] = settling
            f.write(json.dumps(doc, indent=2, ensure_ascii=False))
            f.write("\n")
        print(f"wrote {path}")
    return 0
