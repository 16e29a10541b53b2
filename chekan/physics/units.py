"""Angles and gravity units at the edges of the package.

Inside the model every angle is in radians and every gravity in mGal.
Accepted angle notations (:func:`parse_angle_deg`): ``5°10'``, ``5°10'00"``,
``5°10′00″``, ``5d10m``, ``5d10m30s``, ``-1°50'``, ``±1°50'`` (magnitude), and
decimal degrees ``5.1667``.
"""

from __future__ import annotations

import math
import re

import numpy as np

ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi
ARCMIN_PER_RAD = 180.0 * 60.0 / math.pi
MGAL_PER_GAL = 1000.0

_DMS = re.compile(
    r"""^\s*(?P<sign>[+\-−±]?)\s*
    (?P<deg>\d+(?:\.\d*)?)\s*(?:°|d|deg)\s*
    (?:(?P<min>\d+(?:\.\d*)?)\s*(?:'|′|m|min)\s*)?
    (?:(?P<sec>\d+(?:\.\d*)?)\s*(?:"|″|''|s|sec)\s*)?$""",
    re.VERBOSE,
)
_DECIMAL = re.compile(r"^\s*[+\-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+\-]?\d+)?\s*$")


def parse_angle_deg(text: str) -> float:
    """Parse an angle written in degrees (DMS or decimal) and return decimal degrees.

    ``±`` is accepted and means the magnitude. Minutes and seconds must be < 60.
    Raises ``ValueError`` naming the text when it is not an angle.
    """
    s = str(text).strip()
    if _DECIMAL.match(s):
        return float(s)
    m = _DMS.match(s)
    if not m:
        raise ValueError(f"not an angle: {text!r} (use e.g. 5°10', 5°10'00\", 5d10m or 5.1667)")
    deg = float(m["deg"])
    minutes = float(m["min"]) if m["min"] else 0.0
    seconds = float(m["sec"]) if m["sec"] else 0.0
    if minutes >= 60 or seconds >= 60:
        raise ValueError(f"not an angle: {text!r} (minutes and seconds must be below 60)")
    value = deg + minutes / 60.0 + seconds / 3600.0
    return -value if m["sign"] in ("-", "−") else value


def format_dms(angle_deg: float, seconds: bool = False, sign: str = "auto") -> str:
    """Format decimal degrees as ``5°10'`` (or ``5°10'00"`` with ``seconds=True``).

    ``sign``: ``"auto"`` (minus only), ``"always"`` (+/−) or ``"pm"`` (±, the paper's style).
    """
    neg = angle_deg < 0
    total_s = round(abs(angle_deg) * 3600.0, 3 if seconds else 0)
    if not seconds:
        total_s = round(total_s / 60.0) * 60.0
    d = int(total_s // 3600)
    mnt = int((total_s - 3600 * d) // 60)
    sec = total_s - 3600 * d - 60 * mnt
    body = f"{d}°{mnt:02d}'" if not seconds else f"{d}°{mnt:02d}'{sec:02.0f}\""
    if sign == "pm":
        return "±" + body
    if sign == "always":
        return ("−" if neg else "+") + body
    return ("-" if neg else "") + body


def deg_to_rad(x):
    return np.deg2rad(x)


def rad_to_deg(x):
    return np.rad2deg(x)


def arcsec_to_rad(x):
    scalar = np.isscalar(x)  # a Python or NumPy scalar stays a scalar
    return x / ARCSEC_PER_RAD if scalar else np.asarray(x, dtype=float) / ARCSEC_PER_RAD


def rad_to_arcsec(x):
    scalar = np.isscalar(x)  # a Python or NumPy scalar stays a scalar
    return x * ARCSEC_PER_RAD if scalar else np.asarray(x, dtype=float) * ARCSEC_PER_RAD


def arcmin_to_rad(x):
    scalar = np.isscalar(x)  # a Python or NumPy scalar stays a scalar
    return x / ARCMIN_PER_RAD if scalar else np.asarray(x, dtype=float) / ARCMIN_PER_RAD


def rad_to_arcmin(x):
    scalar = np.isscalar(x)  # a Python or NumPy scalar stays a scalar
    return x * ARCMIN_PER_RAD if scalar else np.asarray(x, dtype=float) * ARCMIN_PER_RAD


def gal_to_mgal(x):
    return x * MGAL_PER_GAL


def mgal_to_gal(x):
    return x / MGAL_PER_GAL


def one_minus_cos(theta_rad):
    """1 − cos θ computed as 2 sin²(θ/2), exact near zero (eq. 14 without g)."""
    s = np.sin(np.asarray(theta_rad, dtype=float) / 2.0)
    return 2.0 * s * s
