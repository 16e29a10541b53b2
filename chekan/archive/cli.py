"""Command-line registrars of the archive layer (cheap to import: no NumPy, no JAX).

``add_parsers(subparsers)`` registers all three; ``chekan/cli/commands.py`` calls it. Standalone:
``python -m chekan.archive archive|reanalyze|history …``.

    chekan archive add RESULT.json… [--db PATH]
    chekan archive list [--serial S] [--db PATH]
    chekan archive show ID [--json] [--db PATH]
    chekan archive export out.csv [--serial S] [--db PATH]
    chekan reanalyze DIR --method classical|map|bayes [--jobs N] [--executor local|dask]
                     [--scheduler ADDR] [--results-dir D] [--db PATH]
    chekan history SERIAL [--param b1 b2 a] [--method M] [--at DATE] [--tolerance-ppm X]
                   [--plot history.png] [--json out.json] [--db PATH]
                   [--export gravtools|csv FILE [--system 1|2] [--reference-b B]
                    [--height-offset-m H] [--valid-until DATE]]

Exit status: 0; 1 when some input/result failed (``reanalyze``, ``archive add``); 2 on an
error (also an output refused by :func:`chekan.files.outputs.check_outputs`); 4 when ``history``
raised an ALARM; 130 interrupted; 141 standard output closed early (``| head``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from chekan import argtypes
from chekan.errors import ChekanError
from chekan.files.kinds import EXPORT, FOLDER, HISTORY, PDF, PNG, SVG
from chekan.files.outputs import SQLITE, Output, check_outputs, run_command
from chekan.options import METHODS

PLOT_KINDS = {".png": PNG, ".pdf": PDF, ".svg": SVG}
PLOT_SUFFIXES = tuple(PLOT_KINDS)
DB_HELP = "archive database (default $CHEKAN_ARCHIVE, else ~/.local/share/chekan/archive.sqlite)"


def _db_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", help=DB_HELP)


def _db(args: argparse.Namespace) -> Output:
    """The archive in use (``--db``, ``$CHEKAN_ARCHIVE`` or the default), resolved before
    the outputs are checked so that no output option can name it unnoticed."""
    from chekan.archive.db import default_db_path

    # the configured location's folders are made ($CHEKAN_ARCHIVE, the default); a --db
    # typed on the command line must lie in an existing folder
    return Output(default_db_path(args.db), writes=SQLITE, makes_folders=args.db is None)


# ----------------------------------------------------------------------------- archive
def _quiet_arg(q: argparse.ArgumentParser) -> None:
    q.add_argument(
        "-q", "--quiet", action="store_true", help="print nothing on success (errors still)"
    )


def _cmd_add(args: argparse.Namespace) -> int:
    from chekan.archive.db import Archive
    from chekan.report.dcc_read import read_result_or_dcc as read_result  # JSON or DCC

    db = _db(args)
    check_outputs(args.results, [db])
    bad = 0
    with Archive(db.path) as a:
        for path in args.results:
            try:
                sid = a.add_result(read_result(path), path, replace=args.replace)
            except ChekanError as e:
                print(f"chekan: error: {e}", file=sys.stderr)
                bad += 1
                continue
            if not args.quiet:
                print(f"{path}: session {sid}")
    return 1 if bad else 0


def _cmd_list(args: argparse.Namespace) -> int:
    from chekan.archive.db import Archive

    db = _db(args)
    check_outputs([], [db])
    with Archive(db.path, readonly=True) as a:
        rows = a.list_sessions(args.serial)
        params = {
            r["session_id"]: r for r in a.parameter_rows(args.serial) if r["parameter"] == "b1"
        }
    print(f"{'id':>5}  {'serial':<10} {'date':<10}  {'method':<9} {'version':<8} {'b1':>11}  input")
    for r in rows:
        b1 = params.get(r["id"])
        b1s = f"{b1['mean']:11.6f}" if b1 else " " * 11
        print(
            f"{r['id']:>5}  {r['serial']:<10} {r['calibrated_on'] or '?':<10}  {r['method']:<9} "
            f"{r['software_version']:<8} {b1s}  {r['input_path']}"
        )
    print(f"{len(rows)} session(s) in {a.path}")
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    from chekan.archive.db import Archive

    db = _db(args)
    check_outputs([], [db])
    with Archive(db.path, readonly=True) as a:
        s = a.get_session(args.id)
    if args.json:
        print(json.dumps(s, indent=2, ensure_ascii=False))
        return 0
    from chekan.results.summary import format_summary

    for k in (
        "id",
        "serial",
        "calibrated_on",
        "method",
        "software_version",
        "input_kind",
        "input_path",
        "input_sha256",
        "created",
        "added",
        "result_path",
        "netcdf_path",
    ):
        print(f"{k:>16}: {s[k] if s[k] is not None else ''}")
    print()
    print(format_summary(s["result"]))
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from chekan.archive.db import Archive

    if (args.out is None) == (args.out_opt is None):
        raise ChekanError("archive export: give the CSV file once, as OUT or as -o/--out")
    out = args.out if args.out is not None else args.out_opt
    db = _db(args)
    check_outputs([db.path], [Output(out, writes=EXPORT)])
    with Archive(db.path, readonly=True) as a:
        n = a.export_csv(out, args.serial)
    if not args.quiet:
        print(f"wrote {out} ({n} parameter rows)")
    return 0


def add_archive_parser(sub: Any) -> argparse.ArgumentParser:
    """``chekan archive add|list|show|export``."""
    p = sub.add_parser("archive", help="the calibration archive: add, list, show, export")
    asub = p.add_subparsers(dest="archive_command", required=True, metavar="ACTION")
    q = asub.add_parser(
        "add",
        help="add result JSON files (idempotent)",
        epilog="exit status: 0 all added (or already there with the same numbers), 1 some "
        "files failed or differ from the archived session (the others were added)",
    )
    q.add_argument("results", nargs="+", help="chekan-result/1 JSON files")
    q.add_argument(
        "--replace",
        action="store_true",
        help="a result whose numbers differ from the archived session of the same input, "
        "method and version replaces it (without: reported, not added, exit 1)",
    )
    _quiet_arg(q)
    _db_arg(q)
    q.set_defaults(func=_cmd_add)
    q = asub.add_parser("list", help="list archived sessions")
    q.add_argument("--serial", help="only this instrument")
    _db_arg(q)
    q.set_defaults(func=_cmd_list)
    q = asub.add_parser("show", help="one session in full")
    q.add_argument("id", type=int, help="session id (see 'archive list')")
    q.add_argument("--json", action="store_true", help="print the stored session as JSON")
    _db_arg(q)
    q.set_defaults(func=_cmd_show)
    q = asub.add_parser("export", help="parameters of every session as CSV (one row each)")
    q.add_argument("out", nargs="?", help="CSV file to write (or -o/--out)")
    _quiet_arg(q)
    q.add_argument("-o", "--out", dest="out_opt", metavar="OUT", help="CSV file to write")
    q.add_argument("--serial", help="only this instrument")
    _db_arg(q)
    q.set_defaults(func=_cmd_export)
    return p


# ----------------------------------------------------------------------------- reanalyze
def _cmd_reanalyze(args: argparse.Namespace) -> int:
    from chekan.archive.reanalyze import reanalyze

    db = _db(args)
    check_outputs([args.dir], [db, Output(args.results_dir, writes=FOLDER)])
    rep = reanalyze(
        args.dir,
        args.method,
        db=str(db.path),
        jobs=args.jobs,
        executor=args.executor,
        scheduler=args.scheduler,
        results_dir=args.results_dir,
        options=_reanalyze_options(args),
        progress=not args.no_progress,
    )
    if not args.no_progress or rep.failed:  # -q: nothing on success
        print(rep.summary())
    if rep.found == 0 and not rep.failed:
        raise ChekanError(
            f"{args.dir}: no chekan-record/1 or chekan-protocol/1 file found (searched "
            "recursively; hidden entries skipped)"
        )
    return 1 if rep.failed else 0


def _reanalyze_options(args: argparse.Namespace) -> dict[str, Any] | None:
    """The calibration options that ``reanalyze``'s flags set (None: the defaults)."""
    opts: dict[str, Any] = {}
    if args.quick:
        opts["quick"] = True
    if args.sampler != "auto":
        opts["sampler"] = args.sampler
    return opts or None


def add_reanalyze_parser(sub: Any) -> argparse.ArgumentParser:
    """``chekan reanalyze DIR --method …``."""
    p = sub.add_parser(
        "reanalyze",
        help="analyse every record/protocol under a folder into the archive",
        epilog="exit status: 0 all done or skipped, 1 some inputs failed (listed; the others "
        "were archived), 2 an error (also: no record or protocol found)",
    )
    p.add_argument("dir", help="folder searched recursively for chekan-record/1 and -protocol/1")
    p.add_argument("--method", choices=METHODS, default="classical")
    p.add_argument(
        "-j",
        "--jobs",
        type=argtypes.integer(1, 1024),
        help="worker processes (default: the CPUs available)",
    )
    p.add_argument("--executor", choices=("local", "dask"), default="local")
    p.add_argument("--scheduler", help="dask: scheduler address (default: a LocalCluster)")
    p.add_argument("--results-dir", help="where result JSONs go (default <archive dir>/results)")
    p.add_argument("--quick", action="store_true", help="bayes: smaller ESS target")
    p.add_argument(
        "--sampler",
        choices=("auto", "emcee"),
        default="auto",
        help="bayes: auto (default) importance sampling where reliable, else emcee; emcee always",
    )
    p.add_argument(
        "-q",
        "--quiet",
        "--no-progress",
        dest="no_progress",
        action="store_true",
        help="no progress bar, and nothing printed on success (failures still listed)",
    )
    _db_arg(p)
    p.set_defaults(func=_cmd_reanalyze)
    return p


# ----------------------------------------------------------------------------- history
def _export_args(args: argparse.Namespace) -> tuple[str, str] | None:
    """``(format, file)`` of ``--export``, its options checked before any work."""
    from chekan.archive.export import check_export

    if args.export is None:
        given = [
            o
            for o, v in (
                ("--system", args.system),
                ("--reference-b", args.reference_b),
                ("--height-offset-m", args.height_offset_m),
                ("--valid-until", args.valid_until),
            )
            if v is not None
        ]
        if given:
            raise ChekanError(f"{', '.join(given)}: only with --export FORMAT FILE")
        return None
    fmt, path = args.export
    check_export(
        path,
        fmt,
        system=args.system,
        reference_b=args.reference_b,
        height_offset_m=args.height_offset_m,
    )
    return fmt, path


def _cmd_history(args: argparse.Namespace) -> int:
    from chekan.archive.db import Archive
    from chekan.archive.history import (
        format_history,
        plot_history,
        stability_history,
        write_history_json,
    )

    db = _db(args)
    kind = PLOT_KINDS.get(Path(args.plot).suffix.lower()) if args.plot else None
    outputs = [Output(args.plot, writes=kind), Output(args.json, writes=HISTORY)]
    check_outputs([db.path], [*outputs, args.export and args.export[1]])
    export = _export_args(args)  # after the guard: a record or an archive gets its message
    if args.plot and kind is None:
        raise ChekanError(
            f"{args.plot}: a plot is written as {', '.join(PLOT_SUFFIXES)} (from the file's "
            "suffix); choose one of them"
        )
    notes: list[str] = []
    with Archive(db.path, readonly=True) as a:
        hist = stability_history(
            a,
            args.serial,
            params=tuple(args.param),
            method=args.method,
            at=args.at,
            tolerance_ppm=args.tolerance_ppm,
            extra_error=not args.no_extra_error,
        )
        # the files first: a standard output closed early (| head) must not cut them short
        written = []
        if export:
            from chekan.archive.export import write_export

            out, notes = write_export(
                export[1],
                export[0],
                a,
                args.serial,
                method=args.method,
                system=args.system,
                reference_b=args.reference_b,
                height_offset_m=args.height_offset_m,
                valid_until=args.valid_until,
            )
            written.append(out)
    if args.plot:
        written.append(plot_history(hist, args.plot))
    if args.json:
        written.append(write_history_json(args.json, hist))
    print(format_history(hist))
    for note in notes:
        print(f"note: export: {note}")
    for path in written:
        print(f"wrote {path}")
    return 4 if any(x["level"] == "ALARM" for x in hist["alarms"]) else 0


def add_history_parser(sub: Any) -> argparse.ArgumentParser:
    """``chekan history SERIAL …``."""
    p = sub.add_parser(
        "history",
        help="scale-factor stability of one instrument over the years",
        epilog="exit status: 0 no alarm (warnings included), 4 an ALARM fired, 2 an error",
    )
    p.add_argument("serial", help="gravimeter serial number")
    p.add_argument("--param", nargs="+", default=["b1", "b2", "a"], help="parameters (b1 b2 a)")
    p.add_argument(
        "--method",
        choices=METHODS,
        help="only this method (default per session: bayes > map > classical)",
    )
    p.add_argument(
        "--at", type=argtypes.date, help="date of the prediction, YYYY-MM-DD (default today)"
    )
    p.add_argument(
        "--tolerance-ppm",
        type=argtypes.positive,
        default=500.0,
        help="alarm threshold for scale-factor changes, ppm (default 500)",
    )
    p.add_argument(
        "--no-extra-error",
        action="store_true",
        help="model no extra per-session error beyond the reported sd",
    )
    p.add_argument("--plot", help="write the history plot (PNG, PDF, SVG)")
    p.add_argument("--json", help="write the history as JSON")
    g = p.add_argument_group(
        "export for survey software",
        "the scale factor as dated periods: each verification from its date to the day "
        "before the next",
    )
    g.add_argument(
        "--export",
        nargs=2,
        metavar=("FORMAT", "FILE"),
        help="write the periods: 'gravtools' (BEV GravTools' gravimeter JSON, "
        "linear_factor = b/b_ref) or 'csv' (b and sd of both systems); an existing FILE "
        "is replaced only by an export of the same kind",
    )
    g.add_argument(
        "--system",
        type=int,
        choices=(1, 2),
        help="gravtools: the quartz system whose scale factor the file carries (required: "
        "GravTools keeps one linear factor per gravimeter)",
    )
    g.add_argument(
        "--reference-b",
        type=argtypes.positive,
        metavar="B",
        help="gravtools: b_ref in mGal/pix, the scale that converted the survey's pixel "
        "readings to mGal (default: the first period's b)",
    )
    g.add_argument(
        "--height-offset-m",
        type=argtypes.real(-10.0, 10.0),
        metavar="H",
        help="gravtools: GravTools' height_offset_m, the sensor's level relative to the "
        "instrument's top, m (negative below it; default 0.0: chekan does not know it)",
    )
    g.add_argument(
        "--valid-until",
        type=argtypes.date,
        metavar="DATE",
        help="end of the last period, YYYY-MM-DD (default 2100-01-01, GravTools' open end)",
    )
    _db_arg(p)
    p.set_defaults(func=_cmd_history)
    return p


def add_parsers(sub: Any) -> None:
    """Register ``archive``, ``reanalyze`` and ``history`` on ``chekan``'s subparsers."""
    add_archive_parser(sub)
    add_reanalyze_parser(sub)
    add_history_parser(sub)


def main(argv: list[str] | None = None) -> int:
    """``python -m chekan.archive``: the three commands without the rest of ``chekan``."""
    from chekan import __version__

    ap = argtypes.Parser(prog="python -m chekan.archive")
    ap.add_argument("-V", "--version", action="version", version=f"chekan {__version__}")
    add_parsers(ap.add_subparsers(dest="command", required=True, metavar="COMMAND"))
    return run_command(lambda: (a := ap.parse_args(argv)).func(a))
