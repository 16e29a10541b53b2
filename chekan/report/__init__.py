"""The calibration certificate: the protocol of Calibr.exe (paper, Fig. 6, items а)–е)),
with every number's uncertainty, the Bayesian budget and diagnostics when present,
figures, and a verdict — as PDF (typst) or one self-contained HTML page, in English
or Russian.

    from chekan.report import render_report
    render_report(result_dict_or_json_path, "calibr_46.pdf", lang="ru")

    chekan report result.json --lang ru --out calibr_46.pdf
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from chekan.errors import ChekanError, FormatError
from chekan.report.cli import add_report_parser
from chekan.report.content import build_report, verdict_of
from chekan.report.document import Report
from chekan.report.i18n import LANGS, check_lang

__all__ = [
    "FORMATS",
    "LANGS",
    "Report",
    "add_report_parser",
    "build_report",
    "render_report",
    "verdict_of",
]

FORMATS = {".pdf": "pdf", ".html": "html", ".htm": "html", ".xml": "dcc"}


def output_format(out: Path, fmt: str | None) -> str:
    """``fmt`` if given (checked), else from the suffix of ``out``."""
    if fmt is not None:
        if fmt not in ("pdf", "html", "dcc"):
            raise ChekanError(f"unknown report format {fmt!r}; choose pdf, html or dcc")
        return fmt
    try:
        return FORMATS[out.suffix.lower()]
    except KeyError:
        raise ChekanError(
            f"{out}: cannot tell the report format from the suffix {out.suffix!r}; "
            "use .pdf, .html or .xml (DCC), or give the format (--format pdf|html|dcc)"
        ) from None


def render_report(
    result: Mapping[str, Any] | str | Path,
    out: str | Path,
    *,
    lang: str = "en",
    fmt: str | None = None,
    tolerance_percent: float = 0.05,
    record_path: str | Path | None = None,
    netcdf_path: str | Path | None = None,
    source: str | Path | None = None,
    keep_figures: str | Path | None = None,
    lab: str | Path | None = None,
    customer: str | None = None,
) -> Path:
    """Render the certificate of ``result`` (a result dict, or the path of its JSON) to ``out``.

    ``fmt``: ``"pdf"`` or ``"html"`` (default: from the suffix of ``out``).
    ``tolerance_percent``: the verdict's tolerance for the reduced error and |instability|.
    ``record_path`` / ``netcdf_path``: the record and posterior NetCDF, when not where the
    result says (relative paths are also tried beside ``source``, the result file).
    ``keep_figures``: also write the figure PNGs into this folder.
    ``lab`` / ``customer``: for ``fmt="dcc"`` (PTB Digital Calibration Certificate, XML): the
    lab file (TOML; default ``$CHEKAN_LAB``) and the customer's name (default: the lab file's).
    Returns the path written. Bad input raises :class:`~chekan.errors.ChekanError`.
    """
    from chekan.results.document import check_result, read_result

    check_lang(lang)
    out = Path(out)
    if out.is_dir():
        raise ChekanError(f"{out}: is a folder; give the certificate's file name")
    kind = output_format(out, fmt)
    if not (
        isinstance(tolerance_percent, int | float)
        and math.isfinite(tolerance_percent)
        and tolerance_percent > 0
    ):
        raise ChekanError(f"tolerance_percent must be a positive number, not {tolerance_percent!r}")
    if isinstance(result, str | Path):
        source = source or result
        result = read_result(result)
    elif isinstance(result, Mapping):
        check_result(dict(result), source or "<result>")
    else:
        raise FormatError(source, None, "a result must be a JSON object (dict)")
    from chekan.files.durable import atomic_output
    from chekan.files.outputs import SYSTEM_ERRNOS

    if kind == "dcc":
        from chekan.report.dcc import write_dcc

        return write_dcc(
            result, out, lab, customer=customer, tolerance_percent=tolerance_percent, lang=lang
        )
    lab_data = _optional_lab(lab)

    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        # the temporary file is opened before the work, so that a folder one cannot write
        # to shows at once; the certificate appears only when it is complete
        with atomic_output(out, "wb") as f:
            rep = build_report(
                result,
                lang=lang,
                tolerance_percent=float(tolerance_percent),
                record_path=record_path,
                netcdf_path=netcdf_path,
                source=source,
                lab=lab_data,
                customer=customer,
            )
            if kind == "pdf":
                from chekan.report.pdf_certificate import certificate_attachments
                from chekan.report.typst_pdf import render_pdf

                data = render_pdf(  # PDF/A-3b carrying the DCC (with a lab) and the result
                    rep,
                    attachments=certificate_attachments(
                        result, lab_data, customer, float(tolerance_percent), lang
                    ),
                )
            else:
                from chekan.report.html_page import render_html

                data = render_html(rep)
            f.write(data)
        if keep_figures is not None:
            folder = Path(keep_figures)
            folder.mkdir(parents=True, exist_ok=True)
            for i, fig in enumerate(rep.figures, start=1):
                with atomic_output(folder / f"fig{i}-{fig.name}.png", "wb") as g:
                    g.write(fig.png)
    except OSError as e:
        if e.errno in SYSTEM_ERRNOS:  # a full disk: exit 1, the file named (atomic_output)
            raise
        raise ChekanError(f"{out}: cannot write the certificate: {e.strerror or e}") from None
    return out


def _optional_lab(lab_path: str | Path | None) -> dict[str, Any] | None:
    """The lab file for a PDF/HTML certificate: ``lab_path`` or ``$CHEKAN_LAB`` if set."""
    import os

    from chekan.report.dcc import LAB_ENV, load_lab

    if lab_path is None and not os.environ.get(LAB_ENV):
        return None
    return load_lab(lab_path)
