"""Read back the text of a PDF and count its images and missing glyphs, with pypdf.

Used by the certificate tests: text per page (``pypdf``'s ``extract_text``), the image
XObjects drawn (``Do``, also inside form XObjects; soft masks not counted) and the
glyphs drawn as ``.notdef`` (code 0 of a two-byte CID font: missing from the font).
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pypdf import PdfReader
from pypdf.generic import ContentStream


@dataclass
class PdfText:
    """Text per page, images drawn, glyphs drawn as .notdef."""

    pages: list[str] = field(default_factory=list)
    n_images: int = 0
    n_notdef: int = 0

    @property
    def text(self) -> str:
        """Every page's text, one page after the other."""
        return "\n".join(self.pages)


def _raw(s: Any) -> bytes:
    """The bytes of a PDF string operand as written in the content stream."""
    if isinstance(s, bytes):
        return bytes(s)
    return bytes(getattr(s, "original_bytes", str(s).encode("latin-1", "replace")))


def _scan(content: ContentStream, resources: Any, reader: PdfReader, out: PdfText, depth=0):
    """Count ``Do`` of images and .notdef glyphs of a content stream (forms recursively)."""
    res = resources.get_object() if resources is not None else {}
    fonts = res.get("/Font", {})
    fonts = fonts.get_object() if fonts else {}
    xobjs = res.get("/XObject", {})
    xobjs = xobjs.get_object() if xobjs else {}
    two_byte = False
    for operands, op in content.operations:
        if op == b"Tf" and operands:
            font = fonts.get(operands[0])
            two_byte = font is not None and font.get_object().get("/Subtype") == "/Type0"
        elif op in (b"Tj", b"'", b'"', b"TJ") and operands and two_byte:
            arg = operands[-1]
            for p in arg if isinstance(arg, list) else [arg]:
                if isinstance(p, str | bytes):
                    b = _raw(p)
                    out.n_notdef += sum(b[k : k + 2] == b"\0\0" for k in range(0, len(b), 2))
        elif op == b"Do" and operands:
            xo = xobjs.get(operands[0])
            if xo is None:
                continue
            xo = xo.get_object()
            if xo.get("/Subtype") == "/Image":
                out.n_images += 1
            elif xo.get("/Subtype") == "/Form" and depth < 8:
                sub = ContentStream(xo, reader)
                _scan(sub, xo.get("/Resources", resources), reader, out, depth + 1)


def read_pdf(pdf: bytes | str | Path) -> PdfText:
    """Text per page and the number of images drawn in a PDF (bytes or a path)."""
    data = pdf if isinstance(pdf, bytes) else Path(pdf).read_bytes()
    reader = PdfReader(io.BytesIO(data))
    out = PdfText()
    for page in reader.pages:
        out.pages.append(page.extract_text())
        content = page.get_contents()
        if content is not None:
            _scan(content, page.get("/Resources"), reader, out)
    return out


def normalize(text: str) -> str:
    """Whitespace collapsed, typographic minus → "-" (to compare with JSON numbers)."""
    return re.sub(r"\s+", " ", text.replace("\u2212", "-")).strip()
