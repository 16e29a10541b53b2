"""Calibration records, format ``chekan-record/1`` (``docs/specs/record-format.md``).

- :mod:`chekan.records.framing` — metadata/header/data framing, shared with
  :mod:`chekan.records.protocol`;
- :mod:`chekan.records.parse` — the vectorised and the line-by-line data parsers;
- :mod:`chekan.records.reader` — :class:`Record` and :func:`read_record`;
- :mod:`chekan.records.writer` — :func:`write_record` (atomic) and :class:`RecordWriter`
  (streaming, crash-safe).

The read-speed benchmark is ``python bench/records_bench.py [PATH]``.
"""

from chekan.records.framing import IncompleteLineWarning
from chekan.records.parse import fast_block as _fast_block
from chekan.records.parse import slow_block as _slow_block
from chekan.records.reader import (
    DEFAULT_COLUMNS,
    FORMAT,
    REQUIRED_COLUMNS,
    REQUIRED_KEYS,
    Record,
    read_record,
    synthetic_record,
)
from chekan.records.reader import synthetic_record as _synthetic
from chekan.records.writer import RecordWriter, write_record

__all__ = [
    "DEFAULT_COLUMNS",
    "FORMAT",
    "REQUIRED_COLUMNS",
    "REQUIRED_KEYS",
    "IncompleteLineWarning",
    "Record",
    "RecordWriter",
    "_fast_block",
    "_slow_block",
    "_synthetic",
    "read_record",
    "synthetic_record",
    "write_record",
]
