"""Write a :class:`~chekan.report.document.Report` as typst source and compile it to PDF.

Every piece of text enters the source as a typst *string literal* (``"…"`` with
``\\`` and ``"`` escaped) inside code, never as markup, so serial numbers or site
names with ``#``, ``$``, ``*``, ``_`` … are printed as they are. Only typst's
bundled fonts are used (Libertinus Serif, DejaVu Sans Mono), so the output does
not depend on the fonts of the machine; both cover Cyrillic.

The PDF is PDF/A-3b; the machine-readable certificate (the DCC, the result JSON) rides in
it as associated files (``pdf.attach``: an embedded file listed in the catalogue's /AF
with its /AFRelationship), so the person's and the program's copies cannot part.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from chekan.errors import ChekanError
from chekan.report.document import Cell, Figure, Heading, KeyValue, Para, Report, Table

PDF_STANDARD: Literal["a-3b"] = "a-3b"  # PDF/A-3: archival, and allows embedded (associated) files
FONT = "Libertinus Serif"
MONO = "DejaVu Sans Mono"
MAX_UNSPLIT_ROWS = 40  # a table up to this many rows is never split over two pages
MAX_KEPT_PARAS = 12  # paragraphs kept on the page of the heading above them
_ALIGN = {"l": "left", "c": "center", "r": "right"}
_BOX = {
    "pass": ('rgb("#e6f4e8")', 'rgb("#2e7d32")'),
    "fail": ('rgb("#fbe7e6")', 'rgb("#b3261e")'),
    "warn": ('rgb("#fff4e0")', 'rgb("#b26a00")'),
}


@dataclass(frozen=True)
class Attachment:
    """A file embedded in the PDF as an associated file: its ``name`` (a plain file name),
    bytes, MIME type, relationship to the document (PDF/A-3 /AFRelationship) and a
    description."""

    name: str
    data: bytes
    mime_type: str
    relationship: Literal["source", "data", "alternative", "supplement"]
    description: str

    def __post_init__(self) -> None:
        bad = "/\\" + "".join(chr(c) for c in range(32))
        if not self.name or self.name.startswith(".") or any(ch in bad for ch in self.name):
            raise ValueError(f"an attachment needs a plain file name, not {self.name!r}")


def _attach(a: Attachment) -> str:
    return (
        f"#pdf.attach({tstr(a.name)}, relationship: {tstr(a.relationship)}, "
        f"mime-type: {tstr(a.mime_type)}, description: {tstr(a.description)})\n"
    )


def tstr(text: str) -> str:
    """``text`` as a typst string literal (control characters other than newline dropped)."""
    out = []
    for ch in str(text):
        if ch == "\\":
            out.append("\\\\")
        elif ch == '"':
            out.append('\\"')
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append(" ")
        elif ord(ch) < 32 or ord(ch) == 127:
            continue
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _cell(c: Cell, *, header: bool = False) -> str:
    body = f"strong({tstr(c.text)})" if (c.bold or header) and c.text else tstr(c.text)
    if c.colspan > 1:
        return f"table.cell(colspan: {c.colspan}, align: center, {body})"
    return body


def _table(tb: Table) -> str:
    aligns = ", ".join(_ALIGN[a] for a in tb.align)
    parts = [
        f"columns: {tb.ncols}",
        f"align: ({aligns},)",
        "stroke: none",
        "inset: (x: 4pt, y: 2.6pt)",
        "table.hline(stroke: 0.8pt)",
    ]
    head_cells = [_cell(c, header=True) for row in tb.header for c in row]
    parts.append("table.header(" + ", ".join(head_cells) + ")")
    parts.append("table.hline(stroke: 0.5pt)")
    nbody = len(tb.rows) - tb.footer_rows
    for i, row in enumerate(tb.rows):
        if i == nbody and tb.footer_rows:
            parts.append("table.hline(stroke: 0.5pt)")
        parts.extend(_cell(c) for c in row)
    parts.append("table.hline(stroke: 0.8pt)")
    inner = "table(\n    " + ",\n    ".join(parts) + ",\n  )"
    if len(tb.rows) + len(tb.header) <= MAX_UNSPLIT_ROWS:  # on one page, caption and all
        if tb.caption:
            return f"#figure(kind: table, caption: {tstr(tb.caption)},\n  {inner})\n"
        return f"#block(breakable: false, {inner})\n"
    # longer than a page can hold: split, the header repeated on the next page
    fig = f"figure(kind: table, caption: {tstr(tb.caption)},\n  {inner})" if tb.caption else inner
    return f"#[#show figure: set block(breakable: true)\n#{fig}]\n"


def _keyvalue(kv: KeyValue) -> str:
    cells = []
    for key, value, mono in kv.rows:
        cells.append(f"text(fill: luma(70), {tstr(key)})")
        cells.append(
            f"text(font: {tstr(MONO)}, size: 7.6pt, {tstr(value)})" if mono else tstr(value)
        )
    whole = "false" if len(kv.rows) <= MAX_UNSPLIT_ROWS else "true"
    return (
        f"#block(breakable: {whole}, table(columns: (auto, 1fr), stroke: none, "
        "inset: (x: 4pt, y: 2.2pt),\n  " + ",\n  ".join(cells) + ",\n))\n"
    )


def _para(p: Para) -> str:
    if p.kind == "strong":
        return f"#strong({tstr(p.text)})\n"
    if p.kind == "note":
        return f"#text(size: 8.5pt, fill: luma(80), {tstr(p.text)})\n"
    if p.kind in _BOX:
        fill, stroke = _BOX[p.kind]
        return (
            f"#block(width: 100%, inset: 7pt, radius: 3pt, fill: {fill}, "
            f"stroke: 0.7pt + {stroke}, strong({tstr(p.text)}))\n"
        )
    return f"#{tstr(p.text)}\n"


def typst_source(
    rep: Report, fig_files: dict[int, str], attachments: Sequence[Attachment] = ()
) -> str:
    """The typst source of ``rep``; ``fig_files`` maps ``id(figure)`` to its file name;
    ``attachments`` (written beside it under their names) are embedded."""
    head = [
        f'#set document(title: {tstr(rep.title + " — " + rep.subtitle)}, author: "chekan")',
        f"#set text(font: {tstr(FONT)}, size: 10pt, lang: {tstr(rep.lang)})",
        "#set par(justify: false, leading: 0.55em, spacing: 0.9em)",
        '#set page(paper: "a4", margin: (x: 1.8cm, top: 2.1cm, bottom: 1.9cm),',
        "  header: context { if counter(page).get().first() > 1 {",
        f"    set text(size: 8pt, fill: luma(100)); {tstr(rep.running_head)}; h(1fr)",
        "  } },",
        "  footer: context align(center, text(size: 8pt, fill: luma(100),",
        f"    {tstr(rep.certificate_id + ' — ' if rep.certificate_id else '')} + "
        'counter(page).display("1 / 1", both: true))))',
        "#show heading.where(level: 1): set text(size: 12pt)",
        "#show heading: set block(above: 1.3em, below: 0.7em)",
        "#show figure: set block(breakable: false)",
        "#show figure.where(kind: table): set figure.caption(position: top)",
        "#show figure.caption: set text(size: 8.5pt)",
        "#show table: set text(size: 8.6pt)",
        "#align(center, stack(spacing: 7pt,",
        f'  text(size: 17pt, weight: "bold", {tstr(rep.title)}),',
        f"  text(size: 11pt, {tstr(rep.subtitle)})))",
        "#v(4pt)",
        "",
    ]
    body: list[str] = []
    blocks = rep.blocks
    i = 0
    while i < len(blocks):
        b = blocks[i]
        if isinstance(b, Heading):
            # a heading and the paragraphs under it stay on one page
            j = i + 1
            while j < len(blocks) and isinstance(blocks[j], Para) and j - i <= MAX_KEPT_PARAS:
                j += 1
            paras = "\n".join(_para(p) for p in blocks[i + 1 : j] if isinstance(p, Para))
            body.append(
                f"#block(breakable: false, sticky: true)[\n"
                f"#heading(level: {b.level}, {tstr(b.text)})\n\n{paras}]\n"
            )
            i = j
            continue
        i += 1
        if isinstance(b, Para):
            body.append(_para(b))
        elif isinstance(b, Table):
            body.append(_table(b))
        elif isinstance(b, KeyValue):
            body.append(_keyvalue(b))
        elif isinstance(b, Figure):
            img = f"image({tstr(fig_files[id(b)])}, width: {100 * b.width:.0f}%)"
            body.append(f"#figure({img}, caption: {tstr(b.caption)})\n")
    return "\n".join(head) + "\n".join(body) + "".join(_attach(a) for a in attachments)


def render_pdf(
    rep: Report, keep_source: Path | None = None, attachments: Sequence[Attachment] = ()
) -> bytes:
    """Compile ``rep`` to PDF/A-3b bytes (in a temporary folder with the figure PNGs),
    ``attachments`` embedded as associated files."""
    import typst

    names = [a.name for a in attachments]
    if len(set(names)) != len(names):
        raise ValueError(f"attachments need distinct names: {names}")

    with tempfile.TemporaryDirectory(prefix="chekan-report-") as tmp:
        root = Path(tmp)
        files: dict[int, str] = {}
        for i, f in enumerate(rep.figures, start=1):
            name = f"fig{i}-{f.name}.png"
            (root / name).write_bytes(f.png)
            files[id(f)] = name
        for a in attachments:
            if a.name in files.values() or a.name == "certificate.typ":
                raise ValueError(f"attachment name {a.name!r} is taken by the document")
            (root / a.name).write_bytes(a.data)
        src = typst_source(rep, files, attachments)
        main = root / "certificate.typ"
        main.write_text(src, encoding="utf-8")
        if keep_source is not None:
            keep_source.write_text(src, encoding="utf-8")
        try:
            return typst.compile(
                str(main),
                root=str(root),
                ignore_system_fonts=True,
                pdf_standards=PDF_STANDARD,
            )
        except Exception as e:  # typst.TypstError: a bug of this module, reported plainly
            raise ChekanError(f"typst could not compile the certificate: {e}") from e
