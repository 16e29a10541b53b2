"""The machine-readable certificate inside the PDF one: what is embedded, and reading it
back.

A PDF certificate (PDF/A-3b) carries the result JSON it was written from
(``chekan-result.json``, relationship Source) and, when a lab file identifies the issuer,
the DCC of the same result (``dcc.xml``, relationship Alternative: the same certificate
for a program). Without a lab file there is no DCC (it needs the laboratory's identity),
only the result. Reading a PDF back refuses one whose DCC and result disagree.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from chekan.errors import ChekanError, FormatError
from chekan.report.dcc import EMBEDDED_NAME, build_dcc, dcc_bytes, result_json_bytes
from chekan.report.typst_pdf import Attachment

DCC_NAME = "dcc.xml"


def certificate_attachments(
    result: Mapping[str, Any],
    lab: Mapping[str, Any] | None,
    customer: str | None,
    tolerance_percent: float,
    lang: str,
) -> list[Attachment]:
    """The files a PDF certificate of ``result`` embeds: the DCC (only with ``lab``, a
    :func:`chekan.report.dcc.load_lab` dict) and the result JSON."""
    out = []
    if lab is not None:
        xml = dcc_bytes(
            build_dcc(
                result, lab, customer=customer, lang=lang, tolerance_percent=tolerance_percent
            )
        )
        out.append(
            Attachment(
                DCC_NAME,
                xml,
                "application/xml",
                "alternative",
                "Digital Calibration Certificate (PTB DCC 3.3.0) of this certificate",
            )
        )
    out.append(
        Attachment(
            EMBEDDED_NAME,
            result_json_bytes(result),
            "application/json",
            "source",
            "the chekan-result/1 this certificate was written from",
        )
    )
    return out


def is_pdf(path: str | os.PathLike) -> bool:
    """True if ``path`` starts as a PDF does."""
    try:
        with open(path, "rb") as f:
            return f.read(5) == b"%PDF-"
    except OSError:
        return False


def embedded_files(path: str | os.PathLike) -> dict[str, bytes]:
    """The embedded files of the PDF at ``path`` by name (FormatError if unreadable)."""
    try:
        import pypdf
    except ImportError:
        raise ChekanError(
            f"{path}: reading a result out of a PDF needs the pypdf package (pip install pypdf)"
        ) from None
    p = Path(path)
    try:
        reader = pypdf.PdfReader(p)
        files = {name: data[0] for name, data in reader.attachments.items() if data}
    except OSError as e:
        raise FormatError(p, None, f"cannot read: {e.strerror or e}") from None
    except Exception as e:  # pypdf's errors for a damaged file: named, not a traceback
        raise FormatError(p, None, f"not a readable PDF: {e}") from None
    return files


def read_pdf_result(path: str | os.PathLike) -> dict[str, Any]:
    """The chekan-result/1 embedded in the PDF certificate at ``path``, checked against
    the DCC beside it when there is one (every value equal, else refused)."""
    import json

    from chekan.report.dcc_read import parse_dcc
    from chekan.results.document import check_result

    p = Path(path)
    files = embedded_files(p)
    blob = files.get(EMBEDDED_NAME)
    if blob is None:
        raise FormatError(p, None, f"this PDF carries no {EMBEDDED_NAME} (not written by chekan)")
    try:
        result = json.loads(blob.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FormatError(p, None, f"the embedded {EMBEDDED_NAME} is unreadable: {e}") from None
    check_result(result, p)
    if DCC_NAME in files:
        from_dcc = parse_dcc(files[DCC_NAME], f"{p} ({DCC_NAME})")
        if from_dcc != result:
            raise FormatError(p, None, f"the embedded {DCC_NAME} and {EMBEDDED_NAME} disagree")
    return result


def read_any_result(path: str | os.PathLike) -> dict[str, Any]:
    """The result of a result JSON, a DCC or a PDF certificate that embeds one."""
    from chekan.report.dcc_read import read_result_or_dcc

    return read_pdf_result(path) if is_pdf(path) else read_result_or_dcc(path)
