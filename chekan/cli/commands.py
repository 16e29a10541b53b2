"""The ``chekan`` command line. Every subcommand has ``--help``.

chekan simulate --out rec.csv [--seed N] [--truth truth.json]
chekan calibrate REC_OR_PROTOCOL --method classical|map|bayes --json result.json
chekan program [FILE]
chekan design [FILE] [--search] [--out best.toml] (expected precision of a tilt program)
chekan emulate …      chekan acquire …      (hardware layer)
chekan demo --out DIR (the main job end to end on the built-in emulator)
chekan warmup [PROGRAM …] (set-up: compile and store the joint model's executables)

The exit statuses of every command are listed in :data:`EXIT_STATUS` (``chekan --help``).
"""

from __future__ import annotations

import argparse
import dataclasses
import warnings
from pathlib import Path

from chekan import __version__, argtypes
from chekan.files.kinds import DESIGN, FOLDER, NETCDF, PROGRAM, RECORD, RESULT, TRUTH, report_kind
from chekan.files.outputs import Output, check_outputs, end_process, run_command, sniff_format
from chekan.options import ANGLE_ERRORS, METHODS

#: ``simulate --report-period-s``: a platform reporting its angles faster than every
#: millisecond is a platform without a report period (0); slower than hourly is no platform.
REPORT_PERIOD_MIN_S, REPORT_PERIOD_MAX_S = 1e-3, 3600.0

EXIT_STATUS = """\
exit status (every command):
  0    done
  1    some inputs failed, the others were done (reanalyze; archive add, also a result
       whose numbers differ from its archived session: --replace); a full disk or an I/O
       error while writing (nothing half-written is left);
       a device error (acquire, demo: e.g. TILT,ERR; emulate)
  2    bad input or usage: a malformed file (file:line: problem), a bad option, or an
       output refused (it is an input of the command, an existing chekan-record/1 or
       chekan-protocol/1 file or SQLite database (the archive), which no output option
       overwrites, or another file chekan reads or writes (a result, program, lab file,
       DCC, PDF, …) that only its own kind replaces; a name with another format's
       suffix (JSON into x.pdf); a folder that does not exist: none is created)
  3    calibrate --strict: the estimate did not converge or was flagged (a hyperparameter
       ended at a bound: diagnostics.problems);
       acquire, demo: a serial link stayed down, acquisition gave up (resume with --resume)
  4    history: an ALARM (a scale-factor change beyond --tolerance-ppm)
  130  interrupted (Ctrl-C; SIGTERM for acquire and emulate)
  141  standard output was closed early (e.g. piped into head): the files were written,
       the rest of the printout dropped quietly

short options (the same in every command that has the option):
  -V/--version  -q/--quiet  -o/--out (the main output file; calibrate: the result JSON)
  -j/--jobs  -v/--verbose
"""


def _cmd_simulate(args) -> int:
    import numpy as np

    from chekan.physics.program import default_program, load_program
    from chekan.records import write_record
    from chekan.records.simulate import Truth, random_truth, simulate_session, write_truth

    check_outputs(
        [args.program], [Output(args.out, writes=RECORD), Output(args.truth, writes=TRUTH)]
    )
    program = load_program(args.program) if args.program else default_program()
    truth = (
        random_truth(np.random.default_rng(args.seed + 10_000), serial=args.serial)
        if args.random_truth
        else Truth(serial=args.serial)
    )
    truth = dataclasses.replace(truth, **_platform_timing(args))
    rec, truth = simulate_session(program, truth, seed=args.seed)
    out = Path(args.out)
    write_record(out, rec)
    if args.truth:
        write_truth(args.truth, truth)
    if not args.quiet:
        print(f"wrote {out} ({rec.t_s.size} samples, {program.describe()})")
        if args.truth:
            print(f"wrote {args.truth} (true parameters)")
    return 0


def _cmd_calibrate(args) -> int:
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.results.document import write_result
    from chekan.results.summary import format_summary

    opts = CalibrationOptions(
        method=args.method,
        hdi_prob=args.hdi_prob,
        settle_s=args.settle_s,
        a_fixed=args.a_fixed,
        seed=args.seed,
        progress=not args.quiet,
        encoder_error=args.encoder_error,
        angle_errors=args.angle_errors,
        angle_bound_arcsec=args.angle_bound_arcsec,
        angle_calibration=args.angle_calibration,
        horizontal_u_pix=args.horizontal_u_pix,
        quick=args.quick,
        sampler=args.sampler,
    )
    json_path = Path(args.json) if args.json else None
    if args.method == "bayes":
        nc = args.netcdf or (json_path.with_suffix(".nc") if json_path else None)
        opts = dataclasses.replace(opts, netcdf=nc)
    check_outputs(
        [args.input, args.angle_calibration],
        [
            Output(json_path, writes=RESULT),
            Output(opts.netcdf, writes=NETCDF),
            Output(args.report, writes=report_kind(args.report)) if args.report else None,
        ],
    )
    if args.report:
        from chekan.report import output_format

        output_format(Path(args.report), None)  # a report it cannot write: before the work
    res = calibrate_file(args.input, opts)
    # the files first: a standard output closed early (| head) must not cut them short
    written = [res["posterior_netcdf"]] if res.get("posterior_netcdf") else []
    if json_path:
        write_result(json_path, res)
        written.insert(0, json_path)
    if args.report:
        from chekan.report import render_report

        written.append(render_report(res, args.report, lang=args.lang))
    if not args.quiet:
        print(format_summary(res))
        for path in written:
            print(f"wrote {path}")
    diag = res.get("diagnostics", {})
    flagged = not diag.get("converged", True) or bool(diag.get("problems"))
    return 3 if flagged and args.strict else 0


def _cmd_program(args) -> int:
    from chekan.physics.program import default_program, load_program

    p = load_program(args.file) if args.file else default_program()
    print(p.describe())
    print("rounds: " + ", ".join(f"{r} about {a.upper()}" for r, a in enumerate(p.round_axes, 1)))
    for s in p.steps:
        about = f"about {s.axis.upper()}" if s.kind == "tilt" else ""
        print(
            f"{s.index:3d}  round {s.round}  {s.label():>9} {about:<7}  "
            f"dwell {s.dwell_s:g} s (settle {s.settle_s:g} s)"
        )
    return 0


def _cmd_design(args) -> int:
    from chekan.design import run_design_command

    check_outputs(
        [args.program, args.angle_calibration],
        [Output(args.out, writes=PROGRAM), Output(args.json, writes=DESIGN)],
    )
    return run_design_command(args)


def _platform_timing(args) -> dict:
    """``Truth`` fields from ``--report-period-s``, ``--report-phase-s``, ``--motion-substeps``."""
    from chekan.errors import ChekanError

    period, phase = args.report_period_s, args.report_phase_s
    if phase is not None and not 0.0 <= phase < period:
        raise ChekanError(
            f"--report-phase-s {phase:g} must lie in [0, --report-period-s) = [0, {period:g})"
            + ("" if period > 0 else ": give --report-period-s first")
        )
    return {
        "platform_report_period_s": period,
        "platform_report_phase_s": phase,
        "motion_substeps": args.motion_substeps,
    }


def _cmd_demo(args) -> int:
    from chekan.demo import run_demo
    from chekan.errors import ChekanError

    check_outputs([], [Output(args.out, writes=FOLDER)])
    rec = Path(args.out) / "record.csv"
    if sniff_format(rec) is not None and b"# operator: chekan demo" not in _head(rec):
        raise ChekanError(
            f"{rec}: refusing to overwrite a record that no demo wrote; choose another --out"
        )
    return run_demo(args.out, quick=args.quick, use_emulator=not args.no_emulator)


def _cmd_warmup(args) -> int:
    from chekan.warmup import default_targets, program_targets, store_summary, warm

    targets = program_targets(args.programs) if args.programs else default_targets()
    say = (lambda _: None) if args.quiet else print
    warm(targets, args.methods or ("map", "bayes"), say=say, force=args.force)
    print(store_summary())
    return 0


def _head(path: Path, n: int = 1 << 16) -> bytes:
    with open(path, "rb") as f:
        return f.read(n)


def build_parser() -> argparse.ArgumentParser:
    ap = argtypes.Parser(
        prog="chekan",
        description="Tilt-method calibration of the Chekan-AM gravimeter.",
        epilog=EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("-V", "--version", action="version", version=f"chekan {__version__}")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("simulate", help="write a simulated 1 Hz record of a whole tilt program")
    p.add_argument(
        "-o", "--out", required=True, help="record to write (chekan-record/1 CSV; a new file)"
    )
    p.add_argument("--seed", type=argtypes.seed, default=0, help="random seed (default 0)")
    p.add_argument("--truth", help="also write the true parameters to this JSON file")
    p.add_argument("--program", help="tilt program TOML (default: the paper's program, 9 h)")
    p.add_argument("--serial", default="SIM-1", help="serial number written into the record")
    p.add_argument(
        "--random-truth", action="store_true", help="draw the instrument's parameters at random"
    )
    p.add_argument(
        "--report-period-s",
        type=argtypes.zero_or(REPORT_PERIOD_MIN_S, REPORT_PERIOD_MAX_S),
        default=0.0,
        help="the platform reports its angles every this many seconds, 0.001 to 3600, and a "
        "row carries the latest report (angles up to a period late; default 0: each row's "
        "own instant)",
    )
    p.add_argument(
        "--report-phase-s",
        type=argtypes.non_negative,
        help="when in the period the reports fall (default: drawn from the seed)",
    )
    p.add_argument(
        "--motion-substeps",
        type=argtypes.integer(1, 1000),
        default=1,
        help="follow the platform and the pendulums at this many steps per sample, keeping "
        "each sample (a platform that moves within a sample; default 1)",
    )
    p.add_argument(
        "-q", "--quiet", action="store_true", help="print nothing on success (errors still)"
    )
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser(
        "calibrate",
        help="estimate b1, b2, a, … from a record or legacy protocol",
        epilog="exit status: 0 done, 2 bad input or a refused output, 3 not converged or "
        "flagged (with --strict)",
    )
    p.add_argument("input", help="chekan-record/1 or chekan-protocol/1 file")
    p.add_argument("--method", choices=METHODS, default="classical")
    p.add_argument("-o", "--json", help="write the chekan-result/1 JSON here")
    p.add_argument("--netcdf", help="bayes: ArviZ posterior NetCDF (default: beside the JSON)")
    p.add_argument("--report", help="also render the certificate (PDF, or .html)")
    p.add_argument("--lang", choices=("ru", "en"), default="en", help="certificate language")
    p.add_argument(
        "--hdi-prob", type=argtypes.probability, default=0.95, help="interval probability (0.95)"
    )
    p.add_argument(
        "--settle-s", type=argtypes.non_negative, help="settling time excluded from dwell means"
    )
    p.add_argument(
        "--a-fixed",
        type=argtypes.real(-0.01, 0.01),
        help="fix a (mGal/pix², record convention; eq. 10 gives ≈ 1.3e-4)",
    )
    p.add_argument(
        "--encoder-error",
        action="store_true",
        help="bayes/map: also model a smooth systematic angle error of the encoder",
    )
    p.add_argument(
        "--angle-errors",
        choices=ANGLE_ERRORS,
        default="systematic",
        help="map/bayes: the platform angle sensors' error: a systematic part per commanded "
        "angle and a scale error shared by all rounds plus a random part per hold "
        "(default), or independent per hold (the model before 0.2)",
    )
    p.add_argument(
        "--angle-bound-arcsec",
        type=argtypes.real(0.0, 3600.0, open_low=True),
        help="map/bayes: bound U of the angle sensors' systematic error, read as rectangular, "
        "u = U/√3 (GUM 4.3.7, Type B); default: the record's platform_angle_bound_y_arcsec or "
        "platform_angle_bound_arcsec, else 3 (the paper)",
    )
    p.add_argument(
        "--angle-calibration",
        metavar="FILE",
        help="the platform's own angle calibration (chekan-angle-calibration/1: per axis, "
        "angle → correction and U at k = 2): the corrections are applied to the measured "
        "angles and its U replaces the bound; default: the record's angle_calibration header",
    )
    p.add_argument(
        "--horizontal-u-pix",
        type=argtypes.real(0.0, 2048.0, open_low=True),
        help="map/bayes, records with rounds about X: standard uncertainty of each pendulum's "
        "horizontal about the CCD centre (Type B), from the instrument's own figure; "
        "default 100 (the model's assumption, 5 %% of the CCD)",
    )
    p.add_argument("--seed", type=argtypes.seed, default=0, help="sampler seed")
    p.add_argument(
        "--quick", action="store_true", help="bayes: cap the sampler at 3000 steps (10 000 without)"
    )
    p.add_argument(
        "--sampler",
        choices=("auto", "emcee"),
        default="auto",
        help="bayes: auto (default) draws the posterior by importance sampling from the fitted "
        "proposal where it is reliable (Pareto k < 0.7, ESS >= 1000 for every reported "
        "quantity), else runs emcee; emcee: emcee always (the reference)",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="exit 3 when the estimate did not converge or is flagged (diagnostics.problems)",
    )
    p.add_argument(
        "-q", "--quiet", action="store_true", help="print nothing on success (errors still)"
    )
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("program", help="show a tilt program (default: the paper's)")
    p.add_argument("file", nargs="?", help="program TOML file")
    p.set_defaults(func=_cmd_program)

    p = sub.add_parser(
        "design", help="expected precision of a tilt program; search for a better one"
    )
    p.add_argument("program", nargs="?", help="program TOML file (default: the paper's)")
    p.add_argument("--search", action="store_true", help="search programs of the same duration")
    p.add_argument(
        "--budget-h",
        type=argtypes.real(0.0, 240.0, open_low=True),
        help="clock-time budget with slews (default: given)",
    )
    p.add_argument(
        "--objective", choices=("b_mean", "b_max", "a"), default="b_mean", help="what to minimise"
    )
    p.add_argument(
        "--min-dwell-s", type=argtypes.positive, default=180.0, help="shortest dwell (180 s)"
    )
    p.add_argument(
        "--min-settle-s", type=argtypes.non_negative, default=120.0, help="shortest settle (120 s)"
    )
    p.add_argument("--top", type=argtypes.count, default=15, help="rows of the ranked table (15)")
    p.add_argument(
        "--angle-bound-arcsec",
        type=float,  # checked by the design's own values (a bad bound: exit 2, named)
        help="bound U of the platform angle sensors' systematic error (default 3; 0: none)",
    )
    p.add_argument(
        "--angle-calibration",
        metavar="FILE",
        help="the platform's own angle calibration (chekan-angle-calibration/1): its U "
        "replaces the bound for the axes it has",
    )
    p.add_argument(
        "--horizontal-u-pix",
        type=argtypes.real(0.0, 2048.0, open_low=True),
        help="programs with rounds about X: standard uncertainty of each pendulum's horizontal "
        "about the CCD centre (default 100, the model's assumption)",
    )
    p.add_argument("-o", "--out", help="write the best program here (TOML; implies --search)")
    p.add_argument("--json", help="write the expected sds and the ranked table here")
    p.set_defaults(func=_cmd_design)

    p = sub.add_parser("demo", help="the main job end to end on the built-in emulator")
    p.add_argument("-o", "--out", default="demo", help="output folder (default ./demo)")
    p.add_argument("--quick", action="store_true", help="short program (minutes → seconds)")
    p.add_argument("--no-emulator", action="store_true", help="simulate the record directly")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser(
        "warmup",
        help="compile the joint model for the default programs and keep it (set-up, minutes)",
        description="Compile and store the executables that map and bayes need for the "
        "shape buckets of the paper's 9 h program (and its 3 h version) and the designer's "
        "xy programs (9 h, 2.6 h), or of the tilt programs given, by calibrating a "
        "simulated session of each: a first calibration of a record in those buckets "
        "then loads instead of compiling.",
    )
    p.add_argument("programs", nargs="*", metavar="PROGRAM", help="tilt programs (TOML)")
    p.add_argument(
        "--method", dest="methods", action="append", choices=("map", "bayes"),
        help="only this method (repeatable; default both)",
    )  # fmt: skip
    p.add_argument("--force", action="store_true", help="calibrate even where stored already")
    p.add_argument("-q", "--quiet", action="store_true", help="print only where it stored")
    p.set_defaults(func=_cmd_warmup)

    _add_optional(sub)
    return ap


def _add_optional(sub) -> None:
    """Subcommands of the other layers (hardware, certificate, archive)."""
    from hw import cli as hwcli

    hwcli.add_emulate_parser(sub)
    hwcli.add_acquire_parser(sub)
    from chekan.report import add_report_parser

    add_report_parser(sub)
    from chekan.live import add_live_parser

    add_live_parser(sub)
    from chekan.archive import cli as archive_cli

    archive_cli.add_parsers(sub)


def _run(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)  # inside: --help into a closed pipe is quiet too
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        return int(args.func(args) or 0)


def main(argv: list[str] | None = None) -> int:
    """Exit status: see :data:`EXIT_STATUS` (a closed stdout ends quietly with 141)."""
    return run_command(_run, argv)


def entry() -> None:
    """The ``chekan`` command (console script, ``python -m chekan.cli``): :func:`main`, then
    :func:`chekan.files.outputs.end_process` (no interpreter teardown). Call :func:`main` to run
    a command inside a Python process."""
    end_process(main())


if __name__ == "__main__":
    entry()
