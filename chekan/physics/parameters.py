"""One table of the parameters a calibration reports: name → unit.

Every module that labels a parameter (results, the joint model's priors, the archive,
the history, validation tables) reads its unit here.
"""

from __future__ import annotations

from types import MappingProxyType

PARAMETER_UNITS = MappingProxyType(
    {
        "b1": "mGal/pix",
        "b2": "mGal/pix",
        "a": "mGal/pix^2",
        "b1_0": "mGal/pix",
        "b2_0": "mGal/pix",
        "eps1_arcmin": "arcmin",
        "eps2_arcmin": "arcmin",
        "dgamma_arcmin": "arcmin",
        "tau_s": "s",
        "drift1_pix_per_h": "pix/h",
        "drift2_pix_per_h": "pix/h",
        "sigma1_pix": "pix",
        "sigma2_pix": "pix",
        "sigma_theta_arcsec": "arcsec",
        "sigma_hold_pix": "pix",
        "slew_error": "",
    }
)
"""Units of every reported parameter, in the order the joint model reports them."""

#: The reported quantities that are functions of the joint model's (θ, β), in this order.
PHYSICAL = (
    "b1",
    "b2",
    "a",
    "b1_0",
    "b2_0",
    "eps1_arcmin",
    "eps2_arcmin",
    "dgamma_arcmin",
    "tau_s",
    "drift1_pix_per_h",
    "drift2_pix_per_h",
)

MODEL_UNITS = MappingProxyType({"K": "pix/rad", "noise_scale": ""})
"""Units of the joint model's internal parameters that are not reported as such."""


LEGACY_UNITS = MappingProxyType({"sigma_e_mgal": "mGal"})
"""Units of what only the model of a legacy protocol reports (the error of a pair mean)."""


def unit_of(name: str) -> str:
    """The unit of a reported or internal parameter ('' when it has none)."""
    for table in (PARAMETER_UNITS, MODEL_UNITS, LEGACY_UNITS):
        if name in table:
            return table[name]
    return ""
