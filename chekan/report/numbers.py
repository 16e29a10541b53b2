"""Number formatting of the certificate: fixed decimals, metrology rounding, powers of ten.

Negative numbers use the typographic minus "−" (U+2212); missing values are "—".
The decimal separator is the point in both languages (as in Calibr.exe protocols).
Rounding and a negative zero's sign are Python's format spec (``z``, PEP 682); what is
written here is only the metrology rule (an uncertainty to ``sig`` digits, its value to the
same decimal place) and the typography, which no formatting library does.
"""

from __future__ import annotations

import math
from typing import TypeGuard

MINUS = "−"
DASH = "—"
_SUP = str.maketrans("0123456789-+", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺")


def is_num(x: object) -> TypeGuard[int | float]:
    """A finite real number (bools excluded)."""
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def fixed(x: object, nd: int, *, sign: bool = False) -> str:
    """``x`` with ``nd`` decimals; ``sign=True`` writes "+" for positive values."""
    if not is_num(x):
        return DASH
    # "z": a value that rounds to zero is written 0.00, never −0.00
    s = f"{float(x):+z.{nd}f}" if sign else f"{float(x):z.{nd}f}"  # type: ignore[arg-type]
    return s.replace("-", MINUS)


def decimals_for(u: float, sig: int = 2) -> int:
    """Decimals that show ``u`` with ``sig`` significant digits (≥ 0)."""
    if not is_num(u) or u == 0:
        return 6
    return max(0, sig - 1 - math.floor(math.log10(abs(u))))


def round_sig(u: float, sig: int = 2) -> float:
    """``u`` rounded to ``sig`` significant digits (to nearest)."""
    if not is_num(u) or u == 0:
        return u
    return float(f"{u:.{sig - 1}e}")


def sci(x: object, sig: int = 4, *, exp: int | None = None) -> str:
    """``x`` as mantissa·10ⁿ with ``sig`` significant digits (or a given exponent)."""
    if not is_num(x):
        return DASH
    xf = float(x)  # type: ignore[arg-type]
    if xf == 0:
        return "0"
    e = math.floor(math.log10(abs(xf))) if exp is None else exp
    mant = xf / 10.0**e
    nd = max(0, sig - 1 - (math.floor(math.log10(abs(mant))) if mant else 0))
    return f"{fixed(mant, nd)}·10{str(e).translate(_SUP)}"


def unc(u: object, sig: int = 2) -> str:
    """An uncertainty with ``sig`` significant digits (powers of ten when tiny or huge)."""
    if not is_num(u):
        return DASH
    uf = round_sig(float(u), sig)  # type: ignore[arg-type]
    if uf == 0:
        return "0"
    if 1e-5 <= abs(uf) < 1e5:
        return fixed(uf, decimals_for(uf, sig))
    return sci(uf, sig)


def value_unc(x: object, u: object, sig: int = 2) -> tuple[str, str]:
    """``(x, u)`` rounded together: u to ``sig`` digits, x to the same decimal place."""
    if not is_num(u) or u == 0:
        return general(x), unc(u)
    uf = round_sig(float(u), sig)  # type: ignore[arg-type]
    if 1e-5 <= abs(uf) < 1e5 and (not is_num(x) or abs(float(x)) >= 1e-4):  # type: ignore[arg-type]
        nd = decimals_for(uf, sig)
        return fixed(x, nd), fixed(uf, nd)
    # powers of ten: the exponent of x, mantissa decimals from u
    xf = float(x) if is_num(x) else uf  # type: ignore[arg-type]
    e = math.floor(math.log10(abs(xf))) if xf else math.floor(math.log10(abs(uf)))
    nd = decimals_for(uf / 10.0**e, sig)
    return (
        f"{fixed(xf / 10.0**e, nd)}·10{str(e).translate(_SUP)}" if is_num(x) else DASH,
        sci(uf, sig),
    )


def general(x: object, sig: int = 6) -> str:
    """A value without an uncertainty: ``sig`` significant digits, powers of ten when tiny."""
    if not is_num(x):
        return DASH
    xf = float(x)  # type: ignore[arg-type]
    if xf == 0:
        return "0"
    if 1e-3 <= abs(xf) < 1e7:
        nd = max(0, sig - 1 - math.floor(math.log10(abs(xf))))
        return fixed(xf, nd)
    return sci(xf, sig)


def plain(x: object) -> str:
    """Shortest form of a round number (``0.05``, ``1024``, ``95``)."""
    if not is_num(x):
        return DASH
    return f"{float(x):z.10g}".replace("-", MINUS)  # type: ignore[arg-type]


def statement(name: str, x: object, big_u: object, unit: str, *, k: float = 2.0) -> str:
    """Metrology style: ``"b₁ = 6.98034 mGal/pix, U = 0.00022 mGal/pix (k = 2)"``; a
    coverage factor other than 2 (Student's t, GUM G.6.4) with two decimals: ``(k = 2.05)``."""
    xs, us = value_unc(x, big_u)
    return f"{name} = {xs} {unit}, U = {us} {unit} (k = {coverage_text(k)})"


def coverage_text(k: object) -> str:
    """A coverage factor as a certificate states it: ``2`` when it rounds to 2.00, else two
    decimals (``2.05``)."""
    if not is_num(k):
        return DASH
    kf = float(k)  # type: ignore[arg-type]
    return "2" if round(kf, 2) == 2.0 else f"{kf:.2f}"
