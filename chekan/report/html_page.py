"""Write a :class:`~chekan.report.document.Report` as one self-contained HTML page.

Styles are inline, figures are ``data:image/png;base64`` URIs: the page loads
nothing from elsewhere. All text is HTML-escaped.
"""

from __future__ import annotations

import base64
from html import escape

from chekan.report.document import Cell, Figure, Heading, KeyValue, Para, Report, Table
from chekan.report.i18n import tr

CSS = """
body { font-family: "Libertinus Serif", "Linux Libertine", Georgia, serif; max-width: 52rem;
       margin: 2rem auto; padding: 0 1rem; color: #111; line-height: 1.4; }
h1.title { text-align: center; margin-bottom: 0.2rem; }
p.subtitle { text-align: center; margin-top: 0; font-size: 1.1rem; }
h2 { font-size: 1.15rem; margin-top: 1.6rem; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.4rem 0 1rem; font-size: 0.88rem; }
table.data { border-top: 1.5px solid #000; border-bottom: 1.5px solid #000; }
table.data thead tr:last-child th { border-bottom: 1px solid #000; }
table.data tr.foot td { border-top: 1px solid #000; }
th, td { padding: 0.15rem 0.5rem; }
td.l { text-align: left; } td.c { text-align: center; } td.r { text-align: right; }
table.kv td:first-child { color: #555; padding-right: 1.2rem; }
caption { caption-side: top; font-size: 0.85rem; text-align: left; padding-bottom: 0.2rem; }
.mono { font-family: "DejaVu Sans Mono", monospace; font-size: 0.8rem; word-break: break-all; }
.note { font-size: 0.85rem; color: #444; }
.box { padding: 0.5rem 0.7rem; border-radius: 4px; font-weight: bold; margin: 0.6rem 0; }
.pass { background: #e6f4e8; border: 1px solid #2e7d32; }
.fail { background: #fbe7e6; border: 1px solid #b3261e; }
.warn { background: #fff4e0; border: 1px solid #b26a00; }
figure { margin: 1rem 0; text-align: center; }
figure img { max-width: 100%; }
figcaption { font-size: 0.85rem; text-align: left; }
"""


def _cell(c: Cell, tag: str, align: str) -> str:
    span = f' colspan="{c.colspan}"' if c.colspan > 1 else ""
    text = escape(c.text)
    if c.bold and tag == "td":
        text = f"<b>{text}</b>"
    cls = f' class="{align}"' if tag == "td" else ""
    return f"<{tag}{span}{cls}>{text}</{tag}>"


def _table(tb: Table, label: str) -> str:
    out = ['<table class="data">']
    if tb.caption:
        out.append(f"<caption>{escape(label)} {escape(tb.caption)}</caption>")
    out.append("<thead>")
    for row in tb.header:
        out.append("<tr>" + "".join(_cell(c, "th", "c") for c in row) + "</tr>")
    out.append("</thead><tbody>")
    nbody = len(tb.rows) - tb.footer_rows
    for i, row in enumerate(tb.rows):
        cls = ' class="foot"' if i >= nbody else ""
        cells = "".join(
            _cell(c, "td", tb.align[j] if j < len(tb.align) else "l") for j, c in enumerate(row)
        )
        out.append(f"<tr{cls}>{cells}</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def _para(p: Para) -> str:
    t = escape(p.text)
    if p.kind == "strong":
        return f"<p><b>{t}</b></p>"
    if p.kind == "note":
        return f'<p class="note">{t}</p>'
    if p.kind in ("pass", "fail", "warn"):
        return f'<div class="box {p.kind}">{t}</div>'
    return f"<p>{t}</p>"


def render_html(rep: Report) -> bytes:
    """The page as UTF-8 bytes."""
    out = [
        "<!DOCTYPE html>",
        f'<html lang="{escape(rep.lang)}"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{escape(rep.title)} — {escape(rep.subtitle)}</title>",
        f"<style>{CSS}</style></head><body>",
        f'<h1 class="title">{escape(rep.title)}</h1>',
        f'<p class="subtitle">{escape(rep.subtitle)}</p>',
    ]
    t = tr(rep.lang)
    nfig = ntab = 0
    for b in rep.blocks:
        if isinstance(b, Heading):
            out.append(f"<h{b.level + 1}>{escape(b.text)}</h{b.level + 1}>")
        elif isinstance(b, Para):
            out.append(_para(b))
        elif isinstance(b, Table):
            ntab += 1 if b.caption else 0
            out.append(_table(b, t("tab_label", n=ntab)))
        elif isinstance(b, KeyValue):
            mono_cls = ' class="mono"'
            rows = "".join(
                f"<tr><td>{escape(k)}</td><td{mono_cls if mono else ''}>{escape(v)}</td></tr>"
                for k, v, mono in b.rows
            )
            out.append(f'<table class="kv">{rows}</table>')
        elif isinstance(b, Figure):
            nfig += 1
            data = base64.b64encode(b.png).decode("ascii")
            cap = f"{t('fig_label', n=nfig)} {b.caption}"
            out.append(
                f'<figure id="fig-{escape(b.name)}"><img alt="{escape(b.name)}" '
                f'style="width:{100 * b.width:.0f}%" src="data:image/png;base64,{data}">'
                f"<figcaption>{escape(cap)}</figcaption></figure>"
            )
    out.append("</body></html>\n")
    return "\n".join(out).encode("utf-8")
