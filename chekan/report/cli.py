"""``chekan report RESULT --out calibr_<serial>.pdf [--lang ru|en] [--format pdf|html|dcc]``
(dcc: PTB Digital Calibration Certificate, XML; needs ``--lab`` or ``$CHEKAN_LAB``).
RESULT is a result JSON, a DCC or a PDF certificate (its embedded result is read)."""

from __future__ import annotations

import argparse
from pathlib import Path

from chekan import argtypes
from chekan.report.i18n import LANGS


def _cmd_report(args: argparse.Namespace) -> int:
    from chekan.files.kinds import report_kind
    from chekan.files.outputs import Output, check_outputs
    from chekan.report import render_report
    from chekan.report.pdf_certificate import read_any_result

    res = read_any_result(args.result)  # a result JSON, a DCC, or a PDF certificate
    out = args.out
    if out is None:
        suffix = {"html": ".html", "dcc": ".xml"}.get(args.format or "pdf", ".pdf")
        out = Path(args.result).with_name(f"calibr_{_safe(str(res['serial']))}{suffix}")
    kind = report_kind(out, args.format)
    check_outputs([args.result, args.record, args.netcdf, args.lab], [Output(out, writes=kind)])
    written = render_report(
        res,
        out,
        lang=args.lang,
        fmt=args.format,
        tolerance_percent=args.tolerance_percent,
        record_path=args.record,
        netcdf_path=args.netcdf,
        source=args.result,
        keep_figures=args.figures,
        lab=args.lab,
        customer=args.customer,
    )
    if not args.quiet:
        print(f"wrote {written}")
    return 0


def _safe(serial: str) -> str:
    """A serial number usable in a file name."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in serial) or "unknown"


def add_report_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``chekan report`` on an ``add_subparsers()`` object; returns the parser."""
    p = subparsers.add_parser(
        "report",
        help="render the calibration certificate (PDF or HTML) from a result JSON",
        description="Render the calibration certificate of a chekan-result/1 JSON: the "
        "protocol of Calibr.exe (items a–f of the paper) with uncertainties, figures and a "
        "verdict.",
    )
    p.add_argument(
        "result",
        help="chekan-result/1 JSON written by 'chekan calibrate', or a DCC (.xml) or PDF "
        "certificate of chekan (the result embedded in it is read)",
    )
    p.add_argument(
        "-o",
        "--out",
        help="certificate to write, .pdf, .html or .xml (DCC) "
        "(default: calibr_<serial>.pdf beside the result)",
    )
    p.add_argument("--lang", choices=LANGS, default="en", help="language (default en)")
    p.add_argument(
        "--format",
        choices=("pdf", "html", "dcc"),
        help="output format (default: from --out; dcc = PTB Digital Calibration Certificate, .xml)",
    )
    p.add_argument(
        "--lab",
        help="lab file (TOML: [lab] name, email, street, city, post_code, country_code, "
        "accreditation; [responsible] name; optional [customer]); default $CHEKAN_LAB; "
        "required for --format dcc",
    )
    p.add_argument("--customer", help="the customer's name (default: the lab file's [customer])")
    p.add_argument(
        "--tolerance-percent",
        type=argtypes.positive,
        default=0.05,
        help="verdict tolerance for the reduced error and |instability of b|, %% (default 0.05)",
    )
    p.add_argument("--record", help="the record, when not at the path the result names")
    p.add_argument("--netcdf", help="the posterior NetCDF, when not at the path the result names")
    p.add_argument("--figures", help="also write the figure PNGs into this folder")
    p.add_argument(
        "-q", "--quiet", action="store_true", help="print nothing on success (errors still)"
    )
    p.set_defaults(func=_cmd_report)
    return p
