"""The calibration archive: SQLite store of results, batch re-analysis, stability history.

Importing this package is cheap (no NumPy/JAX): worker processes import it first.

* :mod:`chekan.archive.db` — :class:`Archive`, ``add_result``, ``list_sessions``,
  ``get_session``, ``export_csv``.
* :mod:`chekan.archive.reanalyze` — ``reanalyze(DIR, method)``, ``solve_many_map``.
* :mod:`chekan.archive.history` — ``stability_history``, ``fit_history``.
* :mod:`chekan.archive.export` — the history as dated periods for survey software
  (GravTools' gravimeter JSON, CSV): ``write_export``.
* :mod:`chekan.archive.cli` — ``add_parsers(subparsers)`` for ``chekan archive|reanalyze|history``.
"""

from chekan.archive.db import (
    Archive,
    add_result,
    default_db_path,
    export_csv,
    get_session,
    list_sessions,
)

__all__ = [
    "Archive",
    "add_result",
    "default_db_path",
    "export_csv",
    "get_session",
    "list_sessions",
]
