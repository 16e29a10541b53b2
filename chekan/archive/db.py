"""The calibration archive: every result of every instrument, in one embedded SQLite file.

Location: ``--db PATH``, else ``$CHEKAN_ARCHIVE``, else
``$XDG_DATA_HOME/chekan/archive.sqlite`` (``~/.local/share/chekan/archive.sqlite``).
Posterior NetCDF files named by ``result["posterior_netcdf"]`` are copied beside it into
``<db dir>/posteriors/<sha256>_<method>.nc``.

Schema (version :data:`SCHEMA_VERSION`, upgraded in place by :func:`migrate`)::

    instruments(id, serial UNIQUE, instrument, model,
                platform_serial (the newest session's))
    sessions(id, instrument_id → instruments, input_path, input_sha256, input_kind,
             calibrated_on (ISO date), metadata_json, method, software_version,
             created, added, result_path, result_json, netcdf_path,
             platform_serial (v2: the gyro-platform of this session),
             UNIQUE(input_sha256, method, software_version))
    parameters(session_id → sessions, name, mean, sd, hdi_low, hdi_high, unit,
               r_hat, ess_bulk, fixed, PRIMARY KEY(session_id, name))

A session is one analysis of one input *content* (its SHA-256) by one method and one
software version; adding it again is a no-op that returns the existing id. Parameters a
method held fixed (``result["fixed"]``) are kept with ``fixed = 1`` and no ``sd``.
The database runs in WAL mode with foreign keys on; every write is one transaction.
"""

from __future__ import annotations

import csv
import datetime as _dt
import json
import math
import os
import shutil
import sqlite3
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from chekan.errors import ChekanError
from chekan.files.durable import atomic_output

SCHEMA_VERSION = 2
PARAM_COLUMNS = ("mean", "sd", "hdi_low", "hdi_high", "unit", "r_hat", "ess_bulk")
EXPORT_COLUMNS = (
    "session_id",
    "serial",
    "calibrated_on",
    "method",
    "software_version",
    "input_kind",
    "input_sha256",
    "input_path",
    "parameter",
    "mean",
    "sd",
    "hdi_low",
    "hdi_high",
    "unit",
    "r_hat",
    "ess_bulk",
    "fixed",
)

_SCHEMA_V1 = """
CREATE TABLE instruments (
    id              INTEGER PRIMARY KEY,
    serial          TEXT NOT NULL UNIQUE,
    instrument      TEXT,
    model           TEXT,
    platform_serial TEXT
);
CREATE TABLE sessions (
    id               INTEGER PRIMARY KEY,
    instrument_id    INTEGER NOT NULL REFERENCES instruments(id) ON DELETE RESTRICT,
    input_path       TEXT NOT NULL,
    input_sha256     TEXT NOT NULL,
    input_kind       TEXT,
    calibrated_on    TEXT,
    metadata_json    TEXT NOT NULL,
    method           TEXT NOT NULL CHECK (method IN ('classical', 'map', 'bayes')),
    software_version TEXT NOT NULL,
    created          TEXT,
    added            TEXT NOT NULL,
    result_path      TEXT,
    result_json      TEXT NOT NULL,
    netcdf_path      TEXT,
    UNIQUE (input_sha256, method, software_version)
);
CREATE INDEX sessions_by_instrument ON sessions (instrument_id, calibrated_on);
CREATE TABLE parameters (
    session_id INTEGER NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    name       TEXT NOT NULL,
    mean       REAL NOT NULL,
    sd         REAL,
    hdi_low    REAL,
    hdi_high   REAL,
    unit       TEXT,
    r_hat      REAL,
    ess_bulk   REAL,
    fixed      INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (session_id, name)
);
"""


# MIGRATIONS[v] upgrades a database at version v-1 to version v (v = 1 creates it).
def _run_script(script: str) -> Callable[[sqlite3.Connection], None]:
    """Statements one by one (``executescript`` would commit the open transaction)."""

    def apply(con: sqlite3.Connection) -> None:
        for stmt in script.split(";"):
            if stmt.strip():
                con.execute(stmt)

    return apply


def _v2_platform_per_session(con: sqlite3.Connection) -> None:
    """Version 2: the gyro-platform of each session (``instruments.platform_serial`` keeps the
    newest session's), filled in from the sessions' stored metadata."""
    con.execute("ALTER TABLE sessions ADD COLUMN platform_serial TEXT")
    rows = con.execute("SELECT id, metadata_json FROM sessions").fetchall()
    for sid, meta in rows:
        serial = (json.loads(meta) or {}).get("platform_serial")
        if serial:
            con.execute("UPDATE sessions SET platform_serial = ? WHERE id = ?", (serial, sid))


MIGRATIONS: dict[int, Callable[[sqlite3.Connection], None]] = {
    1: _run_script(_SCHEMA_V1),
    2: _v2_platform_per_session,
}


def default_db_path(explicit: str | os.PathLike | None = None) -> Path:
    """``explicit`` > ``$CHEKAN_ARCHIVE`` > ``$XDG_DATA_HOME/chekan/archive.sqlite``."""
    if explicit:
        return Path(explicit).expanduser()
    env = os.environ.get("CHEKAN_ARCHIVE")
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "chekan" / "archive.sqlite"


def _explain(e: sqlite3.DatabaseError) -> str:
    """The reason of an SQLite error in a user's words."""
    msg = str(e)
    if "not a database" in msg:
        return "not an SQLite database (is --db or $CHEKAN_ARCHIVE the archive?)"
    if "readonly" in msg or "read-only" in msg:
        return "the archive cannot be written (a read-only file or folder)"
    if "unable to open" in msg:
        return "cannot open the archive (a missing folder, or no permission)"
    return f"archive database error: {msg}"


def _inserted_id(cur: sqlite3.Cursor) -> int:
    """The rowid of the row that the INSERT just run on ``cur`` wrote."""
    assert cur.lastrowid is not None, "an INSERT always sets lastrowid"
    return cur.lastrowid


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _num(v: Any) -> float | None:
    """A finite float or ``None`` (JSON null, NaN, strings that are not numbers)."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def schema_version(con: sqlite3.Connection) -> int:
    """The version recorded in ``schema_version`` (0 for an empty database)."""
    has = con.execute(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'schema_version'"
    ).fetchone()
    if not has:
        return 0
    row = con.execute("SELECT MAX(version) FROM schema_version").fetchone()
    return int(row[0] or 0)


def migrate(con: sqlite3.Connection, target: int = SCHEMA_VERSION) -> int:
    """Apply :data:`MIGRATIONS` up to ``target``, each in its own transaction; return the version.

    A database written by a newer program (version > ``target``) is refused, not touched.
    """
    current = schema_version(con)
    if current > target:
        raise ChekanError(
            f"archive schema version {current} is newer than this program's ({target}); "
            "upgrade chekan"
        )
    while current < target:
        nxt = current + 1
        with con:
            con.execute("BEGIN IMMEDIATE")
            if schema_version(con) == current:  # another process may have migrated meanwhile
                con.execute(
                    "CREATE TABLE IF NOT EXISTS schema_version "
                    "(version INTEGER PRIMARY KEY, applied TEXT NOT NULL)"
                )
                MIGRATIONS[nxt](con)
                con.execute("INSERT INTO schema_version VALUES (?, ?)", (nxt, _now()))
        current = schema_version(con)
    return current


def _session_date(result: dict) -> str | None:
    """Calibration date (ISO, ``YYYY-MM-DD``): ``date``, else metadata ``started``/``date``."""
    meta = result.get("metadata") or {}
    for v in (result.get("date"), meta.get("started"), meta.get("date")):
        if isinstance(v, str) and len(v) >= 10:
            try:
                return _dt.date.fromisoformat(v[:10]).isoformat()
            except ValueError:
                continue
    return None


class ArchiveConflict(ChekanError):
    """A result for an archived session (same input, method and version) with other numbers."""


class Archive:
    """An open archive database; use as a context manager or call :meth:`close`.

    ``readonly=True`` (the commands that only read: ``list``, ``show``, ``export``,
    ``history``) opens an existing archive without writing to it and refuses a missing one,
    so that a mistyped ``--db`` is an error instead of a new empty archive. A file that is
    not an SQLite database, or one that cannot be written where writing is needed, is a
    :class:`~chekan.errors.ChekanError` naming the file.
    """

    def __init__(self, path: str | os.PathLike | None = None, *, readonly: bool = False):
        self.path = default_db_path(path)
        if readonly and not self.path.is_file():
            raise ChekanError(
                f"{self.path}: no archive database there (`chekan archive add` or `chekan "
                "reanalyze` creates one; give --db PATH or set $CHEKAN_ARCHIVE)"
            )
        if not readonly:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self.con = self._open(readonly)
            if readonly and schema_version(self.con) < SCHEMA_VERSION:
                self.con.close()  # an archive of an older version: upgraded once, in place
                self._open(readonly=False).close()
                self.con = self._open(readonly)
        except sqlite3.DatabaseError as e:
            raise ChekanError(f"{self.path}: {_explain(e)}") from e

    def _open(self, readonly: bool) -> sqlite3.Connection:
        if readonly:
            uri = f"{self.path.resolve().as_uri()}?mode=ro"
            con = sqlite3.connect(uri, uri=True, timeout=60.0, isolation_level=None)
        else:
            con = sqlite3.connect(self.path, timeout=60.0, isolation_level=None)
        try:
            con.row_factory = sqlite3.Row
            con.execute("PRAGMA foreign_keys = ON")
            if readonly:
                version = schema_version(con)
                if version == 0:
                    raise ChekanError(f"{self.path}: an SQLite database, but no chekan archive")
                if version > SCHEMA_VERSION:
                    migrate(con)  # raises: written by a newer program
            else:
                con.execute("PRAGMA journal_mode = WAL")
                con.execute("PRAGMA synchronous = NORMAL")
                migrate(con)
        except BaseException:
            con.close()
            raise
        return con

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        self.con.close()

    def __enter__(self) -> Archive:
        return self

    def __exit__(self, exc_type: object, exc: BaseException | None, tb: object) -> None:
        self.close()
        if isinstance(exc, sqlite3.DatabaseError):  # e.g. a write to a read-only archive
            raise ChekanError(f"{self.path}: {_explain(exc)}") from exc

    @property
    def posterior_dir(self) -> Path:
        return self.path.parent / "posteriors"

    # ------------------------------------------------------------------ writing
    def find(self, sha256: str, method: str, software_version: str) -> int | None:
        """Id of the session with this unique key, or ``None``."""
        row = self.con.execute(
            "SELECT id FROM sessions"
            " WHERE input_sha256 = ? AND method = ? AND software_version = ?",
            (sha256, method, software_version),
        ).fetchone()
        return None if row is None else int(row[0])

    def known_hashes(self, method: str, software_version: str) -> set[str]:
        """Input hashes already analysed with ``method`` by ``software_version``."""
        rows = self.con.execute(
            "SELECT input_sha256 FROM sessions WHERE method = ? AND software_version = ?",
            (method, software_version),
        )
        return {r[0] for r in rows}

    def add_result(
        self, result: dict, result_path: str | os.PathLike | None = None, *, replace: bool = False
    ) -> int:
        """Archive one ``chekan-result/1`` dict; return its session id (idempotent).

        The key is (input SHA-256, method, software version); the hash is
        ``result["record_sha256"]``, else computed from the input file if it still exists.
        Adding a result whose numbers (:func:`_content`) equal the archived session's
        returns that session's id; other numbers raise :class:`ArchiveConflict`, unless
        ``replace``: then the session (same id) takes the new result.
        """
        from chekan.results.document import _clean, check_result, sha256_file

        where = str(result_path) if result_path else "<result>"
        check_result(result, where)
        result = _clean(result)  # NumPy → JSON types, NaN → null, as write_result does
        sha = result.get("record_sha256")
        if not sha:
            rec = Path(str(result["record"]))
            if not rec.is_file():
                raise ChekanError(
                    f"{where}: no record_sha256 and input {rec} is not readable; "
                    "cannot identify the session"
                )
            sha = sha256_file(rec)
        method = str(result["method"])
        version = str((result.get("software") or {}).get("version") or "unknown")
        existing = self.find(sha, method, version)
        if existing is not None and not self._replacing(existing, result, where, replace):
            return existing

        nc_src = result.get("posterior_netcdf")
        nc_dst = self._copy_netcdf(nc_src, result_path, sha, method, version) if nc_src else None
        meta = result.get("metadata") or {}
        try:
            with self.con:
                self.con.execute("BEGIN IMMEDIATE")
                existing = self.find(sha, method, version)  # a concurrent writer won the race
                if existing is not None and not self._replacing(existing, result, where, replace):
                    return existing
                inst_id = self._instrument_id(str(result["serial"]), meta, _session_date(result))
                values = (
                    inst_id,
                    str(result["record"]),
                    sha,
                    result.get("input_kind"),
                    _session_date(result),
                    json.dumps(meta, ensure_ascii=False, sort_keys=True),
                    method,
                    version,
                    result.get("created"),
                    _now(),
                    str(Path(result_path).resolve()) if result_path else None,
                    json.dumps(result, ensure_ascii=False, allow_nan=False),
                    str(nc_dst) if nc_dst else None,
                    str(meta["platform_serial"]) if meta.get("platform_serial") else None,
                )
                if existing is None:
                    cur = self.con.execute(
                        f"INSERT INTO sessions ({', '.join(_SESSION_COLUMNS)})"
                        f" VALUES ({', '.join('?' * len(_SESSION_COLUMNS))})",
                        values,
                    )
                    sid = _inserted_id(cur)
                else:
                    sid = existing
                    old_nc = self.con.execute(
                        "SELECT netcdf_path FROM sessions WHERE id = ?", (sid,)
                    ).fetchone()[0]
                    self.con.execute(
                        f"UPDATE sessions SET {', '.join(c + ' = ?' for c in _SESSION_COLUMNS)}"
                        " WHERE id = ?",
                        (*values, sid),
                    )
                    self.con.execute("DELETE FROM parameters WHERE session_id = ?", (sid,))
                    if old_nc and old_nc != str(nc_dst):
                        Path(old_nc).unlink(missing_ok=True)
                self.con.executemany(
                    "INSERT INTO parameters (session_id, name, mean, sd, hdi_low, hdi_high, unit,"
                    " r_hat, ess_bulk, fixed) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    list(_parameter_rows(sid, result)),
                )
                return sid
        except BaseException:
            if nc_dst is not None and self._netcdf_owner(nc_dst) is None:
                nc_dst.unlink(missing_ok=True)
            raise

    def _replacing(self, sid: int, result: dict, where: str, replace: bool) -> bool:
        """Whether archived session ``sid`` is to take ``result`` (same key): ``False`` when
        its numbers are the same; ``True`` with ``replace``; else :class:`ArchiveConflict`."""
        stored = json.loads(
            self.con.execute("SELECT result_json FROM sessions WHERE id = ?", (sid,)).fetchone()[0]
        )
        if _content(stored) == _content(result):
            return False
        if replace:
            return True
        raise ArchiveConflict(
            f"{where}: differs from archived session {sid} (the same input, method "
            f"{result['method']} and software version) in its numbers; not added "
            "(`chekan archive add --replace` replaces the archived result)"
        )

    def _instrument_id(self, serial: str, meta: dict, date: str | None) -> int:
        """Insert the instrument if new; take its descriptive fields from its newest session."""
        fields = {k: meta.get(k) for k in ("instrument", "model", "platform_serial")}
        row = self.con.execute("SELECT id FROM instruments WHERE serial = ?", (serial,)).fetchone()
        if row is None:
            cur = self.con.execute(
                "INSERT INTO instruments (serial, instrument, model, platform_serial)"
                " VALUES (?, ?, ?, ?)",
                (serial, *fields.values()),
            )
            return _inserted_id(cur)
        iid = int(row[0])
        newest = self.con.execute(
            "SELECT MAX(calibrated_on) FROM sessions WHERE instrument_id = ?", (iid,)
        ).fetchone()[0]
        if newest is None or (date is not None and date >= newest):
            for k, v in fields.items():
                if v:
                    self.con.execute(f"UPDATE instruments SET {k} = ? WHERE id = ?", (v, iid))
        return iid

    def _netcdf_owner(self, path: Path) -> int | None:
        row = self.con.execute(
            "SELECT id FROM sessions WHERE netcdf_path = ?", (str(path),)
        ).fetchone()
        return None if row is None else int(row[0])

    def _copy_netcdf(
        self, src: str, result_path: str | os.PathLike | None, sha: str, method: str, version: str
    ) -> Path:
        """Copy the posterior into ``posteriors/<sha>_<method>.nc`` (atomic; never overwrites
        another session's file: then ``<sha>_<method>_<version>.nc``)."""
        p = Path(src)
        if not p.is_absolute() and not p.exists() and result_path:
            p = Path(result_path).parent / p
        if not p.is_file():
            raise ChekanError(f"{result_path or '<result>'}: posterior_netcdf {src} not found")
        self.posterior_dir.mkdir(parents=True, exist_ok=True)
        dst = self.posterior_dir / f"{sha}_{method}.nc"
        if dst.exists() and self._netcdf_owner(dst) is not None:
            safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in version)
            dst = self.posterior_dir / f"{sha}_{method}_{safe}.nc"
        tmp = dst.with_suffix(".nc.tmp")
        shutil.copyfile(p, tmp)
        tmp.replace(dst)
        return dst

    # ------------------------------------------------------------------ reading
    def list_sessions(self, serial: str | None = None) -> list[dict]:
        """Sessions (without the result JSON), oldest calibration first."""
        sql = (
            "SELECT s.id, i.serial, s.calibrated_on, s.method, s.software_version, s.input_kind,"
            " s.input_path, s.input_sha256, s.created, s.added, s.result_path, s.netcdf_path,"
            " s.platform_serial"
            " FROM sessions s JOIN instruments i ON i.id = s.instrument_id"
        )
        args: tuple = ()
        if serial is not None:
            sql += " WHERE i.serial = ?"
            args = (str(serial),)
        sql += " ORDER BY i.serial, s.calibrated_on IS NULL, s.calibrated_on, s.id"
        return [dict(r) for r in self.con.execute(sql, args)]

    def get_session(self, session_id: int) -> dict:
        """One session: its columns, ``metadata``, ``result`` and ``parameters`` by name."""
        row = self.con.execute(
            "SELECT s.*, i.serial, i.instrument, i.model, i.platform_serial AS"
            " instrument_platform_serial FROM sessions s"
            " JOIN instruments i ON i.id = s.instrument_id WHERE s.id = ?",
            (int(session_id),),
        ).fetchone()
        if row is None:
            raise ChekanError(f"archive {self.path}: no session {session_id}")
        out = dict(row)
        out["metadata"] = json.loads(out.pop("metadata_json"))
        out["result"] = json.loads(out.pop("result_json"))
        out["parameters"] = {
            r["name"]: {k: r[k] for k in (*PARAM_COLUMNS, "fixed")}
            for r in self.con.execute(
                "SELECT * FROM parameters WHERE session_id = ? ORDER BY name", (int(session_id),)
            )
        }
        return out

    def instruments(self) -> list[dict]:
        return [dict(r) for r in self.con.execute("SELECT * FROM instruments ORDER BY serial")]

    def parameter_rows(self, serial: str | None = None) -> list[dict]:
        """One row per (session, parameter) in :data:`EXPORT_COLUMNS` order."""
        sql = (
            "SELECT s.id AS session_id, i.serial, s.calibrated_on, s.method, s.software_version,"
            " s.input_kind, s.input_sha256, s.input_path, p.name AS parameter, p.mean, p.sd,"
            " p.hdi_low, p.hdi_high, p.unit, p.r_hat, p.ess_bulk, p.fixed"
            " FROM parameters p JOIN sessions s ON s.id = p.session_id"
            " JOIN instruments i ON i.id = s.instrument_id"
        )
        args: tuple = ()
        if serial is not None:
            sql += " WHERE i.serial = ?"
            args = (str(serial),)
        sql += " ORDER BY i.serial, s.calibrated_on IS NULL, s.calibrated_on, s.id, p.name"
        return [dict(r) for r in self.con.execute(sql, args)]

    def export_csv(self, path: str | os.PathLike, serial: str | None = None) -> int:
        """Write :meth:`parameter_rows` as CSV (floats as ``repr``: exact round trip).

        Returns the number of data rows. Empty fields are missing values.
        """
        rows = self.parameter_rows(serial)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path, newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(EXPORT_COLUMNS)
            for r in rows:
                w.writerow(["" if r[c] is None else _csv_value(r[c]) for c in EXPORT_COLUMNS])
        return len(rows)


_SESSION_COLUMNS = (
    "instrument_id",
    "input_path",
    "input_sha256",
    "input_kind",
    "calibrated_on",
    "metadata_json",
    "method",
    "software_version",
    "created",
    "added",
    "result_path",
    "result_json",
    "netcdf_path",
    "platform_serial",
)


def _content(result: dict) -> tuple:
    """What makes two results of one session the same: serial, date, parameters (the
    archived numbers); not when or from which path it was written."""
    rows = sorted(r[1:] for r in _parameter_rows(0, result))
    return str(result.get("serial")), _session_date(result), rows


def _csv_value(v: Any) -> str:
    return repr(v) if isinstance(v, float) else str(v)


def read_export_csv(path: str | os.PathLike) -> list[dict]:
    """Read a file written by :meth:`Archive.export_csv` back into typed rows."""
    floats = {"mean", "sd", "hdi_low", "hdi_high", "r_hat", "ess_bulk"}
    ints = {"session_id", "fixed"}
    out = []
    with open(path, newline="", encoding="utf-8") as f:
        for r in csv.DictReader(f):
            row: dict[str, Any] = {}
            for k, v in r.items():
                if v == "":
                    row[k] = None
                elif k in floats:
                    row[k] = float(v)
                elif k in ints:
                    row[k] = int(v)
                else:
                    row[k] = v
            out.append(row)
    return out


def _parameter_rows(sid: int, result: dict) -> Iterable[tuple]:
    """Rows of ``parameters`` from ``result["parameters"]`` and ``result["fixed"]``."""
    from chekan.results.document import UNITS

    params = result.get("parameters") or {}
    for name, e in params.items():
        mean = _num(e.get("mean"))
        if mean is None:
            continue
        yield (
            sid,
            name,
            mean,
            *(_num(e.get(k)) for k in ("sd", "hdi_low", "hdi_high")),
            e.get("unit") or UNITS.get(name),
            _num(e.get("r_hat")),
            _num(e.get("ess_bulk")),
            0,
        )
    for name, v in (result.get("fixed") or {}).items():
        mean = _num(v)
        if mean is not None and name not in params:
            yield (sid, name, mean, None, None, None, UNITS.get(name), None, None, 1)


# ---------------------------------------------------------------------- module-level API
def add_result(
    result: dict,
    result_path: str | os.PathLike | None = None,
    *,
    db: str | None = None,
    replace: bool = False,
) -> int:
    """:meth:`Archive.add_result` on the archive at ``db`` (default: :func:`default_db_path`)."""
    with Archive(db) as a:
        return a.add_result(result, result_path, replace=replace)


def list_sessions(serial: str | None = None, *, db: str | None = None) -> list[dict]:
    with Archive(db, readonly=True) as a:
        return a.list_sessions(serial)


def get_session(session_id: int, *, db: str | None = None) -> dict:
    with Archive(db, readonly=True) as a:
        return a.get_session(session_id)


def export_csv(path: str | os.PathLike, serial: str | None = None, *, db: str | None = None) -> int:
    with Archive(db, readonly=True) as a:
        return a.export_csv(path, serial)
