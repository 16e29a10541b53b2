"""Tilt-program design: the expected precision of b₁, b₂ and a from the Fisher information.

- :mod:`chekan.design.layout` — design values, the program laid out as a record is
  binned, its clock time with slews, the damping lag's mixing (:func:`lagged_means`);
- :mod:`chekan.design.information` — sensitivities of the exact equilibrium, the
  expected information and the Laplace covariance (:func:`expected_precision`);
- :mod:`chekan.design.search` — candidate programs within a clock-time budget
  (:func:`search_programs`);
- :mod:`chekan.design.command` — ``chekan design``: text tables, TOML, JSON.
"""

from chekan.design.command import (
    candidate_row,
    design_json,
    format_precision,
    format_table,
    precision_json,
    program_toml,
    run_design_command,
    write_program_toml,
)
from chekan.design.information import (
    C_PRIOR_VAR_PIX2,
    DRIFT_PRIOR_VAR_PIX2,
    OBJECTIVES,
    THETA_NAMES,
    ExpectedPrecision,
    Sensitivities,
    expected_precision,
    information_blocks,
    sensitivities,
)
from chekan.design.layout import (
    DesignValues,
    Lagged,
    Layout,
    lagged_means,
    program_clock_s,
    program_layout,
)
from chekan.design.search import (
    HIGHEST_ANGLE_ARCMIN,
    LOWEST_ANGLE_ARCMIN,
    MIN_DWELL_S,
    MIN_SETTLE_S,
    MIN_SETTLED_S,
    SCHEMES,
    SEARCH_SPACE,
    Candidate,
    ProgramSpec,
    SearchResult,
    program_within_budget,
    search_programs,
    spec_angles_arcmin,
    spec_program,
)
from chekan.errors import ChekanError
from chekan.physics.units import ARCSEC_PER_RAD

__all__ = [
    "ARCSEC_PER_RAD",
    "C_PRIOR_VAR_PIX2",
    "DRIFT_PRIOR_VAR_PIX2",
    "HIGHEST_ANGLE_ARCMIN",
    "LOWEST_ANGLE_ARCMIN",
    "MIN_DWELL_S",
    "MIN_SETTLED_S",
    "MIN_SETTLE_S",
    "OBJECTIVES",
    "SCHEMES",
    "SEARCH_SPACE",
    "THETA_NAMES",
    "Candidate",
    "ChekanError",
    "DesignValues",
    "ExpectedPrecision",
    "Lagged",
    "Layout",
    "ProgramSpec",
    "SearchResult",
    "Sensitivities",
    "candidate_row",
    "design_json",
    "expected_precision",
    "format_precision",
    "format_table",
    "information_blocks",
    "lagged_means",
    "precision_json",
    "program_clock_s",
    "program_layout",
    "program_toml",
    "program_within_budget",
    "run_design_command",
    "search_programs",
    "sensitivities",
    "spec_angles_arcmin",
    "spec_program",
    "write_program_toml",
]
