"""The vendored DCC 3.3.0 schema and its imports, validated offline.

Every import's ``schemaLocation`` is mapped to the copy in ``schemas/`` and remote access
is forbidden (``allow="local"``), so validation never reaches the network
(``schemas/README.md`` names each file's source and licence).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

SCHEMA_VERSION = "3.3.0"
SCHEMAS = Path(__file__).resolve().parent / "schemas"
DCC_LOCATION = "https://ptb.de/dcc/v3.3.0/dcc.xsd"
SI_LOCATION = "https://ptb.de/si/v2.2.1/SI_Format.xsd"
DSIG_LOCATION = "https://www.ptb.de/dcc/d-sig/xmldsig-core-schema.xsd"
QUDT_LOCATION = "https://www.ptb.de/si/v2.2.1/qudt/quantitykind.xsd"
#: import location → the vendored file
LOCAL_FILES = {
    DCC_LOCATION: "dcc.xsd",
    SI_LOCATION: "SI_Format.xsd",
    DSIG_LOCATION: "xmldsig-core-schema.xsd",
    QUDT_LOCATION: "quantitykind.xsd",
}


def _local(uri: str) -> str:
    """The vendored file of ``uri`` (a file URI), or ``uri`` unchanged."""
    name = LOCAL_FILES.get(uri)
    return (SCHEMAS / name).as_uri() if name else uri


@functools.lru_cache(maxsize=1)
def dcc_schema() -> Any:
    """The DCC 3.3.0 schema with D-SI 2.2.1, xmldsig and the QUDT stand-in, all local."""
    import xmlschema

    return xmlschema.XMLSchema(
        str(SCHEMAS / "dcc.xsd"), uri_mapper=_local, allow="local", defuse="always"
    )


def validate_dcc(source: str | os.PathLike | bytes) -> None:
    """Raise ``xmlschema.XMLSchemaValidationError`` if ``source`` (a path or the document's
    bytes) is not a valid DCC 3.3.0."""
    data = Path(source).read_bytes() if not isinstance(source, bytes) else source
    dcc_schema().validate(data.decode("utf-8"))
