"""Read back the text and count the images of a PDF — enough for the PDFs typst writes.

No third-party package: objects (also inside object streams), Flate streams, Type0
fonts with ``/ToUnicode`` CMaps (and simple fonts as Latin-1), the text operators
``Tj TJ ' "`` positioned by ``cm``/``Tm``/``Td``, and ``Do`` of image and form
XObjects. Text comes back line by line per page (spans at the same height joined
by a space), which is what the tests need to check numbers and labels.
"""

from __future__ import annotations

import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

_WS = b" \t\r\n\x00\x0c"
_DELIM = b"()<>[]{}/%"


@dataclass(frozen=True)
class Ref:
    num: int


class Name(str):
    """A PDF name (``/Type`` → ``Name("Type")``)."""


@dataclass
class PdfText:
    pages: list[str] = field(default_factory=list)
    n_images: int = 0  # image XObjects drawn (Do), soft masks not counted
    n_notdef: int = 0  # glyphs drawn as .notdef (code 0 of a CID font): missing in the font

    @property
    def text(self) -> str:
        return "\n".join(self.pages)


class _Lexer:
    def __init__(self, data: bytes, pos: int = 0):
        self.d = data
        self.i = pos

    def _skip(self) -> None:
        d, n = self.d, len(self.d)
        while self.i < n:
            c = d[self.i]
            if c in _WS:
                self.i += 1
            elif c == 0x25:  # % comment
                while self.i < n and d[self.i] not in b"\r\n":
                    self.i += 1
            else:
                return

    def token(self) -> Any:
        """The next token: bytes (strings), Name, int/float, or str (delimiters, keywords)."""
        self._skip()
        d, n = self.d, len(self.d)
        if self.i >= n:
            return None
        c = d[self.i : self.i + 1]
        if c == b"(":
            return self._literal()
        if c == b"<":
            if d[self.i : self.i + 2] == b"<<":
                self.i += 2
                return "<<"
            j = d.index(b">", self.i)
            hexs = re.sub(rb"\s", b"", d[self.i + 1 : j])
            self.i = j + 1
            if len(hexs) % 2:
                hexs += b"0"
            return bytes.fromhex(hexs.decode("ascii"))
        if c == b">" and d[self.i : self.i + 2] == b">>":
            self.i += 2
            return ">>"
        if c in (b"[", b"]", b"{", b"}"):
            self.i += 1
            return c.decode()
        if c == b"/":
            j = self.i + 1
            while j < n and d[j] not in _WS and d[j] not in _DELIM:
                j += 1
            name = re.sub(
                rb"#([0-9A-Fa-f]{2})", lambda m: bytes([int(m.group(1), 16)]), d[self.i + 1 : j]
            )
            self.i = j
            return Name(name.decode("latin-1"))
        j = self.i
        while j < n and d[j] not in _WS and d[j] not in _DELIM:
            j += 1
        if j == self.i:  # stray delimiter
            self.i += 1
            return c.decode("latin-1")
        word = d[self.i : j].decode("latin-1")
        self.i = j
        try:
            return int(word)
        except ValueError:
            try:
                return float(word)
            except ValueError:
                return word

    def _literal(self) -> bytes:
        d = self.d
        i = self.i + 1
        depth = 1
        out = bytearray()
        esc = {ord("n"): 10, ord("r"): 13, ord("t"): 9, ord("b"): 8, ord("f"): 12}
        while i < len(d):
            c = d[i]
            if c == 0x5C:  # backslash
                i += 1
                e = d[i]
                if e in esc:
                    out.append(esc[e])
                    i += 1
                elif 0x30 <= e <= 0x37:
                    j = i
                    while j < min(i + 3, len(d)) and 0x30 <= d[j] <= 0x37:
                        j += 1
                    out.append(int(d[i:j], 8) & 0xFF)
                    i = j
                elif e in b"\r\n":
                    i += 2 if d[i : i + 2] == b"\r\n" else 1
                else:
                    out.append(e)
                    i += 1
                continue
            if c == 0x28:
                depth += 1
            elif c == 0x29:
                depth -= 1
                if depth == 0:
                    self.i = i + 1
                    return bytes(out)
            out.append(c)
            i += 1
        self.i = i
        return bytes(out)

    def value(self, tok: Any = None) -> Any:
        """One PDF object (dicts, arrays, ``n g R`` references)."""
        tok = self.token() if tok is None else tok
        if tok == "<<":
            out: dict[str, Any] = {}
            while True:
                k = self.token()
                if k == ">>" or k is None:
                    return out
                out[str(k)] = self.value()
        if tok == "[":
            arr = []
            while True:
                t = self.token()
                if t == "]" or t is None:
                    return arr
                arr.append(self.value(t))
        if isinstance(tok, int):
            save = self.i
            t2 = self.token()
            if isinstance(t2, int):
                t3 = self.token()
                if t3 == "R":
                    return Ref(tok)
            self.i = save
        return tok


class _Pdf:
    def __init__(self, data: bytes):
        self.data = data
        self.objs: dict[int, Any] = {}
        self.streams: dict[int, bytes] = {}
        for m in re.finditer(rb"(?<![0-9])(\d+)\s+(\d+)\s+obj\b", data):
            num = int(m.group(1))
            lx = _Lexer(data, m.end())
            val = lx.value()
            self.objs[num] = val
            lx._skip()
            if isinstance(val, dict) and data.startswith(b"stream", lx.i):
                s = lx.i + 6
                if data[s : s + 2] == b"\r\n":
                    s += 2
                elif data[s : s + 1] in (b"\n", b"\r"):
                    s += 1
                length = val.get("Length")
                if isinstance(length, int):
                    raw = data[s : s + length]
                else:
                    raw = data[s : data.index(b"endstream", s)].rstrip(b"\r\n")
                self.streams[num] = raw
        for num, val in list(self.objs.items()):
            if isinstance(val, dict) and val.get("Type") == "ObjStm":
                self._objstm(num, val)

    def _objstm(self, num: int, d: dict) -> None:
        body = self.stream(num)
        lx = _Lexer(body)
        heads = [lx.token() for _ in range(2 * int(d.get("N", 0)))]
        first = int(d.get("First", 0))
        for k in range(0, len(heads), 2):
            lx2 = _Lexer(body, first + int(heads[k + 1]))
            self.objs.setdefault(int(heads[k]), lx2.value())

    def get(self, v: Any) -> Any:
        seen = 0
        while isinstance(v, Ref) and seen < 32:
            v = self.objs.get(v.num)
            seen += 1
        return v

    def stream(self, num: int) -> bytes:
        raw = self.streams.get(num, b"")
        filt = self.get(self.objs.get(num, {}).get("Filter"))
        filters = filt if isinstance(filt, list) else [filt] if filt else []
        for f in filters:
            if f == "FlateDecode":
                raw = zlib.decompress(raw)
            else:  # images etc.: not needed for text
                return b""
        return raw

    def stream_of(self, ref: Any) -> bytes:
        return self.stream(ref.num) if isinstance(ref, Ref) else b""


def _cmap(data: bytes) -> tuple[dict[int, str], int]:
    """ToUnicode CMap → (code → text, code length in bytes)."""
    out: dict[int, str] = {}
    nbytes = 2
    m = re.search(rb"begincodespacerange\s*<([0-9A-Fa-f]+)>", data)
    if m:
        nbytes = max(1, len(m.group(1)) // 2)

    def u(hexs: bytes) -> str:
        b = bytes.fromhex(hexs.decode())
        return b.decode("utf-16-be", "replace")

    for blk in re.findall(rb"beginbfchar(.*?)endbfchar", data, re.S):
        for src, dst in re.findall(rb"<([0-9A-Fa-f]+)>\s*<([0-9A-Fa-f]*)>", blk):
            out[int(src, 16)] = u(dst)
    for blk in re.findall(rb"beginbfrange(.*?)endbfrange", data, re.S):
        for lo, hi, rest in re.findall(
            rb"<([0-9A-Fa-f]+)>\s*<([0-9A-Fa-f]+)>\s*(<[0-9A-Fa-f]*>|\[[^\]]*\])", blk
        ):
            a, b = int(lo, 16), int(hi, 16)
            if rest.startswith(b"["):
                for k, h in enumerate(re.findall(rb"<([0-9A-Fa-f]*)>", rest)):
                    out[a + k] = u(h)
            else:
                base = bytes.fromhex(rest[1:-1].decode())
                for k in range(b - a + 1):
                    last = int.from_bytes(base[-2:], "big") + k if len(base) >= 2 else k
                    out[a + k] = (base[:-2] + last.to_bytes(2, "big")).decode(
                        "utf-16-be", "replace"
                    )
    return out, nbytes


def _mul(m: tuple, n: tuple) -> tuple:
    a, b, c, d, e, f = m
    A, B, C, D, E, F = n
    return (
        a * A + b * C,
        a * B + b * D,
        c * A + d * C,
        c * B + d * D,
        e * A + f * C + E,
        e * B + f * D + F,
    )


_ID = (1.0, 0.0, 0.0, 1.0, 0.0, 0.0)


@dataclass
class _Font:
    cmap: dict[int, str]
    nbytes: int
    widths: dict[int, float]
    default: float


class _Page:
    def __init__(self, pdf: _Pdf):
        self.pdf = pdf
        self.spans: list[tuple[float, float, float, float, str]] = []  # y, x0, x1, size, text
        self.images = 0
        self.notdef = 0
        self._fonts: dict[int, _Font] = {}

    def _font(self, ref: Any) -> _Font:
        key = ref.num if isinstance(ref, Ref) else id(ref)
        if key not in self._fonts:
            f = self.pdf.get(ref) or {}
            tu = f.get("ToUnicode")
            cmap, nb = (
                _cmap(self.pdf.stream(tu.num))
                if isinstance(tu, Ref)
                else ({}, 2 if f.get("Subtype") == "Type0" else 1)
            )
            widths: dict[int, float] = {}
            default = 0.0
            if f.get("Subtype") == "Type0":
                desc = self.pdf.get((self.pdf.get(f.get("DescendantFonts")) or [None])[0]) or {}
                default = float(desc.get("DW", 1000))
                w = self.pdf.get(desc.get("W")) or []
                k = 0
                while k < len(w):
                    first = int(w[k])
                    nxt = self.pdf.get(w[k + 1]) if k + 1 < len(w) else None
                    if isinstance(nxt, list):
                        for j, v in enumerate(nxt):
                            widths[first + j] = float(v)
                        k += 2
                    else:
                        for c in range(first, int(nxt) + 1):
                            widths[c] = float(w[k + 2])
                        k += 3
            else:
                fc = int(f.get("FirstChar", 0))
                for j, v in enumerate(self.pdf.get(f.get("Widths")) or []):
                    widths[fc + j] = float(v)
                default = 500.0
            self._fonts[key] = _Font(cmap, nb, widths, default)
        return self._fonts[key]

    def _decode(self, s: bytes, font: _Font) -> tuple[str, float]:
        """Text of a string and its advance in text space units (1/1000 em)."""
        nb = font.nbytes
        codes = [int.from_bytes(s[k : k + nb], "big") for k in range(0, len(s), nb)]
        adv = sum(font.widths.get(c, font.default) for c in codes)
        if nb == 2:
            self.notdef += codes.count(0)
        if not font.cmap and nb == 1:
            return s.decode("latin-1"), adv
        return "".join(font.cmap.get(c, "\ufffd") for c in codes), adv

    def run(self, content: bytes, resources: Any, ctm: tuple = _ID, depth: int = 0) -> None:
        res = self.pdf.get(resources) or {}
        fonts = self.pdf.get(res.get("Font")) or {}
        xobjs = self.pdf.get(res.get("XObject")) or {}
        lx = _Lexer(content)
        ops: list[Any] = []
        stack: list[tuple] = []
        tm = lm = _ID
        font = _Font({}, 1, {}, 500.0)
        size = 10.0
        leading = 0.0
        while True:
            tok = lx.token()
            if tok is None:
                break
            if tok in ("[", "<<"):
                ops.append(lx.value(tok))
                continue
            if not isinstance(tok, str) or isinstance(tok, Name):
                ops.append(tok)
                continue
            op = tok
            if op == "q":
                stack.append(ctm)
            elif op == "Q":
                ctm = stack.pop() if stack else _ID
            elif op == "cm" and len(ops) >= 6:
                ctm = _mul(tuple(float(x) for x in ops[-6:]), ctm)
            elif op == "BT":
                tm = lm = _ID
            elif op == "Tm" and len(ops) >= 6:
                tm = lm = tuple(float(x) for x in ops[-6:])
            elif op in ("Td", "TD") and len(ops) >= 2:
                tx, ty = float(ops[-2]), float(ops[-1])
                if op == "TD":
                    leading = -ty
                lm = tm = _mul((1, 0, 0, 1, tx, ty), lm)
            elif op == "TL" and ops:
                leading = float(ops[-1])
            elif op == "T*":
                lm = tm = _mul((1, 0, 0, 1, 0, -leading), lm)
            elif op == "Tf" and len(ops) >= 2:
                font = self._font(fonts.get(str(ops[-2])))
                size = float(ops[-1])
            elif op in ("Tj", "'", '"', "TJ") and ops:
                arg = ops[-1]
                if op in ("'", '"'):
                    lm = tm = _mul((1, 0, 0, 1, 0, -leading), lm)
                parts = arg if isinstance(arg, list) else [arg]
                text, adv = "", 0.0
                for p in parts:
                    if isinstance(p, bytes):
                        t, a = self._decode(p, font)
                        text += t
                        adv += a
                    elif isinstance(p, int | float):
                        adv -= float(p)
                m = _mul(tm, ctm)
                scale = (m[0] ** 2 + m[1] ** 2) ** 0.5 * size
                self.spans.append((m[5], m[4], m[4] + adv / 1000.0 * scale, scale, text))
            elif op == "Do" and ops:
                ref = xobjs.get(str(ops[-1]))
                xo = self.pdf.get(ref) or {}
                if xo.get("Subtype") == "Image":
                    self.images += 1
                elif xo.get("Subtype") == "Form" and isinstance(ref, Ref) and depth < 8:
                    mat = xo.get("Matrix") or list(_ID)
                    self.run(
                        self.pdf.stream(ref.num),
                        xo.get("Resources", resources),
                        _mul(tuple(float(x) for x in mat), ctm),
                        depth + 1,
                    )
            ops = []

    def text(self) -> str:
        """Spans grouped into lines by height; a space where there is a gap between spans."""
        lines: list[tuple[float, list[tuple[float, float, float, str]]]] = []
        for y, x0, x1, size, s in sorted(self.spans, key=lambda v: (-v[0], v[1])):
            if lines and abs(lines[-1][0] - y) < 2.5:
                lines[-1][1].append((x0, x1, size, s))
            else:
                lines.append((y, [(x0, x1, size, s)]))
        out = []
        for _, items in lines:
            items.sort()
            text, end = "", None
            for x0, x1, size, s in items:
                if end is not None and x0 - end > 0.12 * size and not text.endswith(" "):
                    text += " "
                text += s
                end = x1
            out.append(text)
        return "\n".join(out)


def read_pdf(pdf: bytes | str | Path) -> PdfText:
    """Text per page and the number of images drawn in a PDF (bytes or a path)."""
    data = pdf if isinstance(pdf, bytes) else Path(pdf).read_bytes()
    doc = _Pdf(data)
    roots = [
        v
        for v in doc.objs.values()
        if isinstance(v, dict) and v.get("Type") == "Pages" and "Parent" not in v
    ]
    out = PdfText()

    def walk(node: dict, inherited: Any) -> None:
        res = node.get("Resources", inherited)
        for kid in doc.get(node.get("Kids")) or []:
            k = doc.get(kid)
            if not isinstance(k, dict):
                continue
            if k.get("Type") == "Pages":
                walk(k, res)
                continue
            page = _Page(doc)
            contents = doc.get(k.get("Contents"))
            refs = contents if isinstance(contents, list) else [k.get("Contents")]
            body = b"\n".join(doc.stream_of(r) for r in refs)
            page.run(body, k.get("Resources", res))
            out.pages.append(page.text())
            out.n_images += page.images
            out.n_notdef += page.notdef

    for r in roots:
        walk(r, None)
    return out


def normalize(text: str) -> str:
    """Whitespace collapsed, typographic minus → "-" (to compare with JSON numbers)."""
    return re.sub(r"\s+", " ", text.replace("\u2212", "-")).strip()
