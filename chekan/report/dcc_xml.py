"""Building blocks of the DCC document: namespaced elements, texts in the certificate's
languages, D-SI quantities, and numbers written at their meaning.

A value of the result is written with ``repr`` (the shortest decimal that reads back as
the same float); a value converted to SI by a power of ten is the same decimal with its
point moved (981922.05 mGal → 9.8192205 m s⁻², never 9.819220500000002); one converted
by an irrational factor (arcminute → radian) is written to 15 significant digits.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from decimal import Decimal

DCC_NS = "https://ptb.de/dcc"
SI_NS = "https://ptb.de/si"
K_COVERAGE = 2.0
P_COVERAGE = 0.9545
RAD_PER_ARCMIN = math.pi / 10800.0
RAD_PER_ARCSEC = math.pi / 648000.0

ET.register_namespace("dcc", DCC_NS)
ET.register_namespace("si", SI_NS)

Words = Mapping[str, str]  # a text by language code


def d(tag: str) -> str:
    """``tag`` in the DCC namespace."""
    return f"{{{DCC_NS}}}{tag}"


def s(tag: str) -> str:
    """``tag`` in the D-SI namespace."""
    return f"{{{SI_NS}}}{tag}"


def sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    """A child ``tag`` of ``parent`` with ``text`` and attributes."""
    el = ET.SubElement(parent, tag, attrib)
    if text is not None:
        el.text = text
    return el


def contents(el: ET.Element, words: Words | str, langs: Sequence[str]) -> ET.Element:
    """``dcc:content`` children of ``el``: one per language of ``langs`` for ``words``, or
    one without a language for a proper name (a str)."""
    if isinstance(words, str):
        sub(el, d("content"), words)
    else:
        for lang in langs:
            sub(el, d("content"), words[lang], lang=lang)
    return el


def text(parent: ET.Element, tag: str, words: Words | str, langs: Sequence[str]) -> ET.Element:
    """A ``dcc:textType`` / ``dcc:richContentType`` child ``tag`` holding ``words``."""
    return contents(sub(parent, d(tag)), words, langs)


# ----------------------------------------------------------------------------- numbers


def num(value: float) -> str:
    """A value of the result as written: the shortest decimal of the float."""
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"a DCC value must be finite, not {x!r}")
    return repr(x)


def scaled(value: float, factor: float) -> str:
    """``value`` × ``factor`` at its meaning: a power-of-ten factor moves the decimal point
    of ``num(value)`` exactly; another factor gives 15 significant digits."""
    exp = math.log10(factor)
    if exp == round(exp):
        dec = Decimal(num(value)).scaleb(round(exp)).normalize()
        return _decimal_text(dec)
    return f"{float(value) * factor:.15g}"


def _decimal_text(dec: Decimal) -> str:
    """A Decimal as a D-SI decimal (plain when short, else with an exponent)."""
    _sign, digits, exp = dec.as_tuple()
    assert isinstance(exp, int)
    if -7 <= exp + len(digits) <= 16:
        out = format(dec, "f")
    else:
        out = format(dec, "e").replace("e+", "e")
    return out


# ----------------------------------------------------------------------------- D-SI


def real(
    parent: ET.Element,
    label: str,
    value: str,
    unit: str,
    expanded: tuple[str, str] | None = None,
    *,
    tag: str = "real",
) -> ET.Element:
    """An ``si:real`` (or another ``tag`` of that type) of ``value`` (text) in ``unit``,
    with its expanded uncertainty ``(U, k)`` (texts) as D-SI 2.2.1 states it."""
    r = sub(parent, s(tag))
    sub(r, s("label"), label)
    sub(r, s("value"), value)
    sub(r, s("unit"), unit)
    if expanded is not None:
        big_u, k = expanded
        mu = sub(sub(r, s("measurementUncertaintyUnivariate")), s("expandedMU"))
        sub(mu, s("valueExpandedMU"), big_u)
        sub(mu, s("coverageFactor"), k)
        sub(mu, s("coverageProbability"), num(P_COVERAGE))
        sub(mu, s("distribution"), "normal" if float(k) == K_COVERAGE else "t")
    return r


def quantity(parent: ET.Element, ref: str, name: Words | str, langs: Sequence[str]) -> ET.Element:
    """A ``dcc:quantity`` with its name (its value is added by the caller)."""
    q = sub(parent, d("quantity"), refType=ref)
    text(q, "name", name, langs)
    return q


def hybrid_real(
    q: ET.Element,
    label: str,
    value: float,
    own_unit: str,
    si_unit: str,
    factor: float,
    expanded: tuple[float, float] | None = None,
) -> None:
    """An ``si:hybrid`` of ``value`` in ``own_unit`` and in ``si_unit`` (× ``factor``)."""
    h = sub(q, s("hybrid"))
    own_u = si_u = None
    if expanded is not None:
        own_u = (num(expanded[0]), num(expanded[1]))
        si_u = (scaled(expanded[0], factor), num(expanded[1]))
    real(h, label, num(value), own_unit, own_u)
    real(h, label, scaled(value, factor), si_unit, si_u)


def no_quantity(parent: ET.Element, ref: str, name: Words, what: Words | str, langs) -> None:
    """A ``dcc:quantity`` that is words, not a number (``dcc:noQuantity``)."""
    q = quantity(parent, ref, name, langs)
    contents(sub(q, d("noQuantity")), what, langs)
