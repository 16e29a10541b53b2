"""Read back a DCC written by :mod:`chekan.report.dcc`: the chekan-result/1 dict it carries.

The result JSON is embedded (``dcc:byteData`` ``chekan-result.json``); every parameter's
value and expanded uncertainty in the DCC's ``si:real`` elements must equal the embedded
result's bit for bit (both are written with ``repr`` precision), else the file is refused.
:func:`chekan.report.pdf_certificate.read_any_result` reads a result JSON, a DCC or a PDF
certificate alike.
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from chekan.errors import FormatError
from chekan.report.dcc import DCC_NS, EMBEDDED_NAME, SI_NS, UNITS, expanded_uncertainties

ROOT_TAG = f"{{{DCC_NS}}}digitalCalibrationCertificate"
#: where an si:real states its expanded uncertainty (D-SI 2.2.1)
UNC_PATH = "/".join(
    f"{{{SI_NS}}}{t}" for t in ("measurementUncertaintyUnivariate", "expandedMU", "valueExpandedMU")
)


def is_dcc(path: str | os.PathLike) -> bool:
    """True if ``path`` is an XML file whose root is ``dcc:digitalCalibrationCertificate``."""
    try:
        with open(path, "rb") as f:
            head = f.read(512).lstrip()
        if not head.startswith(b"<"):
            return False
        for _event, el in ET.iterparse(path, events=("start",)):
            return el.tag == ROOT_TAG
    except (OSError, ET.ParseError):
        return False
    return False


def read_dcc(path: str | os.PathLike) -> dict[str, Any]:
    """The chekan-result/1 dict of the DCC at ``path`` (checked against its si:real values)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise FormatError(p, None, f"cannot read: {e.strerror or e}") from None
    return parse_dcc(data, p)


def parse_dcc(data: bytes, src: str | Path) -> dict[str, Any]:
    """The chekan-result/1 dict of the DCC ``data`` (``src`` names it in errors)."""
    from chekan.results.document import check_result

    p = src
    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise FormatError(p, e.position[0], f"not well-formed XML: {e}") from None
    if root.tag != ROOT_TAG:
        raise FormatError(p, None, "not a DCC (root is not dcc:digitalCalibrationCertificate)")
    blob = None
    for bd in root.iter(f"{{{DCC_NS}}}byteData"):
        if bd.findtext(f"{{{DCC_NS}}}fileName") == EMBEDDED_NAME:
            blob = bd.findtext(f"{{{DCC_NS}}}dataBase64")
    if blob is None:
        raise FormatError(p, None, f"this DCC carries no {EMBEDDED_NAME} (not written by chekan)")
    try:
        result = json.loads(base64.b64decode(blob, validate=True).decode("utf-8"))
    except (binascii.Error, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FormatError(p, None, f"the embedded {EMBEDDED_NAME} is unreadable: {e}") from None
    check_result(result, p)
    _check_numbers(p, root, result)
    return result


def _check_numbers(p: str | Path, root: ET.Element, result: dict[str, Any]) -> None:
    """Every parameter's si:real (own unit) equals the embedded mean and U exactly."""
    big_u = expanded_uncertainties(result)
    seen = set()
    for q in root.iter(f"{{{DCC_NS}}}quantity"):
        ref = q.get("refType") or ""
        name = ref.removeprefix("chekan_")
        par = result["parameters"].get(name)
        if par is None:
            continue
        real = q.find(f"{{{SI_NS}}}hybrid/{{{SI_NS}}}real")
        if real is None:
            raise FormatError(p, None, f"{name}: no si:real in its quantity")
        value = float(real.findtext(f"{{{SI_NS}}}value") or "nan")
        unc = real.findtext(UNC_PATH)
        if (
            value != float(par["mean"])
            or real.findtext(f"{{{SI_NS}}}unit") != UNITS.get(par.get("unit", ""), ("",))[0]
        ):
            raise FormatError(p, None, f"{name}: the DCC's value differs from the embedded result")
        if (unc is None) != (name not in big_u) or (
            unc is not None and float(unc) != big_u[name][0]
        ):
            raise FormatError(p, None, f"{name}: the DCC's U differs from the embedded result")
        seen.add(name)
    unseen = [
        n for n, v in result["parameters"].items() if v.get("unit") in UNITS and n not in seen
    ]
    if unseen:
        raise FormatError(p, None, f"parameter(s) {', '.join(unseen)} missing from the DCC")


def read_result_or_dcc(path: str | os.PathLike) -> dict[str, Any]:
    """:func:`read_dcc` for a DCC file, else :func:`chekan.results.document.read_result`."""
    from chekan.results.document import read_result

    return read_dcc(path) if is_dcc(path) else read_result(Path(path))
