"""The results database: SQLite, one row per run, keyed by the job's content hash.

Each row is written in its own transaction by the one process that owns the
store (workers return rows; they never write), so a process killed at any moment
leaves every finished row and no partial one (SQLite's write-ahead log rolls an
unfinished transaction back). Rerunning a sweep skips the keys already present.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import sqlite3
from collections.abc import Iterator
from dataclasses import fields as dataclass_fields
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.files import open_regular
from depotbench.core.output import write_text_atomic
from depotbench.eval.metrics.record import (
    ADDED_FIELDS,
    FIELDS,
    RECORD_VERSION,
    UNKNOWN_FINGERPRINT,
    RunIdentity,
    RunRecord,
)

_KIND_OF_TYPE = {"str": str, "int": int, "float": float}
_KINDS = {f.name: _KIND_OF_TYPE[str(f.type).split(" | ")[0]] for f in dataclass_fields(RunRecord)}
"""Each column's Python type, from ``RunRecord``'s annotations (one source of truth)."""
_NULLABLE = {f.name for f in dataclass_fields(RunRecord) if str(f.type).endswith("| None")}
_SQL = {str: "TEXT", int: "INTEGER", float: "REAL"}
_KIND_NAMES = {str: "text", int: "an integer", float: "a number"}


def _column(name: str) -> str:
    return f"{name} {_SQL[_KINDS[name]]}{' PRIMARY KEY' if name == 'key' else ''}"


VERSIONS = "tracker_fingerprints"
"""The meta entry of the tracker fingerprints the last sweep into the store ran."""
SQLITE_HEADER = b"SQLite format 3\x00"
RELABELLED = ("sequence", "family", "seed", "knobs")
"""What a resumed row takes from its job now: where its sequence is and what it is called,
none of it in the key."""
LOCK_WAIT_S = 30.0
"""How long a write waits for another program's lock on the file (a viewer, a backup)."""


class StoreError(InputError):
    """A results database that cannot be used: the message names the file and the cause."""


def store_error(path: Path, exc: sqlite3.Error) -> StoreError:
    """One line for what SQLite says, naming the file and what to do (the messages of
    SQLite's error codes, not one "not a database" for all of them)."""
    text = str(exc)
    causes = {
        "database is locked": "another program holds it locked (a viewer, a backup); close it and run again",
        "database or disk is full": "the disk is full; the rows written so far are kept: free space, rerun",
        "unable to open database file": "cannot be opened (a missing, unreadable or read-only folder)",
        "attempt to write a readonly database": "is read-only",
        "disk I/O error": "cannot be read or written (disk I/O error)",
    }
    for needle, cause in causes.items():
        if needle in text:
            return StoreError(f"{path}: {cause}")
    return StoreError(f"{path}: not a depotbench results database ({text})")


JSON_COLUMNS = ("knobs", "parameters", "detector_config", "settings")
"""Columns that hold a JSON object as text: a table spreads them, a label reads them."""


def checked_row(row: dict[str, Any], where: str, remedy: str) -> dict[str, Any]:
    """``row`` (some or all columns) with each value of its column's type and each JSON
    column an object, or ``StoreError`` naming ``where`` and the column: a row is read from
    SQLite (which keeps whatever it is given) or a run's record.json, and a value edited by
    hand (``ate_rmse_m = 'oops'``, ``settings = '{'``) would otherwise be a TypeError in a
    mean or a JSONDecodeError in a label, far from its file."""
    for name, value in row.items():
        kind = _KINDS[name]
        if value is None and (name in _NULLABLE or kind is str):
            continue
        good = isinstance(value, kind) and not isinstance(value, bool)
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            row[name], good = float(value), True
        elif kind is int and isinstance(value, float) and value.is_integer():
            row[name], good = int(value), True  # older stores kept some counts in REAL columns
        if good and name in JSON_COLUMNS:
            try:
                good = isinstance(json.loads(value), dict)
            except (ValueError, RecursionError):
                good = False
            if not good:
                raise StoreError(f"{where}: {name} is {value[:80]!r}, not a JSON object; {remedy}")
        if not good:
            raise StoreError(f"{where}: {name} is {value!r:.80}, not {_KIND_NAMES[kind]}; {remedy}")
    return row


class ResultStore:
    """``readonly`` opens an existing database for reading only: a report never changes it,
    and reads it from a read-only place."""

    def __init__(self, path: Path, readonly: bool = False) -> None:
        self.path = path
        self.readonly = readonly
        self._missing: tuple[str, ...] = ()
        """Columns of ``ADDED_FIELDS`` an earlier version's store lacks: read as empty, and a
        resumed store gains them (its old rows keep them empty)."""
        existing = path.exists()
        if existing or readonly:
            self._check_existing()  # read-only: a refused file is left byte for byte as it was
        try:
            if readonly:
                self._db = self._open_readonly()
            else:
                self._db = sqlite3.connect(path, timeout=LOCK_WAIT_S)
                self._db.execute("PRAGMA journal_mode=WAL")
                # A commit appends to the log without fsync (3.7 ms a row here): a killed process
                # still leaves every committed row; only a power cut may lose the last few,
                # which a resumed sweep runs again. The file is never left corrupt either way.
                self._db.execute("PRAGMA synchronous=NORMAL")
                self._db.execute(f"CREATE TABLE IF NOT EXISTS runs ({', '.join(_column(f) for f in FIELDS)})")
                for name in self._missing:  # an earlier version's store, resumed: its rows keep NULL
                    self._db.execute(f"ALTER TABLE runs ADD COLUMN {_column(name)}")
                self._missing = ()
                self._db.execute("CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value TEXT)")
                self._db.commit()
        except sqlite3.Error as exc:
            raise store_error(path, exc) from None

    def _open_readonly(self) -> sqlite3.Connection:
        uri = f"{self.path.resolve().as_uri()}?mode=ro"
        try:
            db = sqlite3.connect(uri, uri=True, timeout=LOCK_WAIT_S)
            db.execute("SELECT count(*) FROM runs").fetchone()
            return db
        except sqlite3.OperationalError as exc:
            if "unable to open" not in str(exc):
                raise
        # A write-ahead-log database on a read-only mount: nothing can write it, so SQLite
        # may read it as immutable (without the shared-memory file it cannot create).
        db = sqlite3.connect(f"{uri}&immutable=1", uri=True)
        db.execute("SELECT count(*) FROM runs").fetchone()
        return db

    def _check_existing(self) -> None:
        """Refuse a file that is not a results database of this record version, reading it only."""
        path = self.path
        try:
            with os.fdopen(open_regular(path, 1 << 50, "results database"), "rb") as handle:
                header = handle.read(len(SQLITE_HEADER))
        except FileNotFoundError:
            raise StoreError(f"{path}: no results database here") from None
        except OSError as exc:
            raise StoreError(f"{path}: cannot be read ({exc.strerror or exc})") from None
        if not header:
            return  # an empty file is an empty database: SQLite starts it
        if header != SQLITE_HEADER:
            raise StoreError(f"{path}: not a depotbench results database (not an SQLite file)")
        try:
            db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=LOCK_WAIT_S)
            try:
                tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
                columns = [row[1] for row in db.execute("PRAGMA table_info(runs)")]
            finally:
                db.close()
        except sqlite3.Error as exc:
            if "unable to open" in str(exc) and not self.readonly:
                return  # a WAL database in a read-only folder: the write opens it, or says why
            raise store_error(path, exc) from None
        if not tables:
            return
        missing = tuple(f for f in FIELDS if f not in columns)
        if "runs" in tables and set(columns) <= set(FIELDS) and set(missing) <= set(ADDED_FIELDS):
            self._missing = missing
            return
        if "runs" not in tables or set(columns) != set(FIELDS):
            raise StoreError(
                f"{path}: its runs table has other columns than record version {RECORD_VERSION}; "
                "give a new output folder"
            )

    def _write(self, sql: str, params: list | tuple) -> None:
        """One statement in its own transaction: the row is there whole, or not at all."""
        try:
            with self._db:
                self._db.execute(sql, params)
        except sqlite3.Error as exc:
            raise store_error(self.path, exc) from None

    def _read(self, sql: str, params: tuple = ()) -> list[tuple]:
        try:
            return self._db.execute(sql, params).fetchall()
        except sqlite3.Error as exc:
            raise store_error(self.path, exc) from None

    def close(self) -> None:
        """Close; a writer first leaves write-ahead logging, so that the file alone holds every
        row and a reader (``report``) opens it without making -wal and -shm files beside it."""
        if not self.readonly:  # with another reader open the log stays; SQLite reads it still
            with contextlib.suppress(sqlite3.OperationalError):
                self._db.execute("PRAGMA journal_mode=DELETE")
        self._db.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def keys(self) -> set[str]:
        return {row[0] for row in self._read("SELECT key FROM runs")}

    def failed_keys(self) -> set[str]:
        """The keys of failed runs (a program's exit, time limit or unreadable output)."""
        found = self._read("SELECT key FROM runs WHERE failure IS NOT NULL AND failure != ''")
        return {row[0] for row in found}

    def older_versions(self, current: dict[str, str]) -> list[tuple[str, str, int]]:
        """(tracker, fingerprint, rows) of each program version of a tracker in ``current``
        (label: its fingerprint now) other than its current one: a row written before
        fingerprints counts as ``unknown``. A sweep keeps such rows apart: their keys are not
        its jobs', so they are neither reused nor summarised."""
        fingerprint = "tracker_fingerprint" if "tracker_fingerprint" not in self._missing else "NULL"
        found = self._read(
            f"SELECT tracker, COALESCE({fingerprint}, ?), count(*) FROM runs GROUP BY 1, 2 ORDER BY 1, 2",
            (UNKNOWN_FINGERPRINT,),
        )
        return [(t, f, n) for t, f, n in found if t in current and f != current[t]]

    def set_versions(self, current: dict[str, str]) -> None:
        """Remember the tracker fingerprints the last sweep ran (label: fingerprint), so that a
        reader of the folder (``report``) keeps the older versions' rows apart too."""
        self.set_meta(VERSIONS, json.dumps(current, sort_keys=True))

    def current_records(self) -> list[RunRecord]:
        """Every run but those of an older version of a tracker the last sweep ran."""
        text = self.meta(VERSIONS)
        current = json.loads(text) if text else {}
        return [r for r in self.records() if current.get(r.tracker, r.program_version) == r.program_version]

    def remove_version(self, tracker: str, fingerprint: str) -> None:
        """Delete the rows of one program version of a tracker (``older_versions``), in one
        transaction."""
        self._write(
            "DELETE FROM runs WHERE tracker = ? AND COALESCE(tracker_fingerprint, ?) = ?",
            (tracker, UNKNOWN_FINGERPRINT, fingerprint),
        )

    def relabel(self, runs: list[RunIdentity]) -> int:
        """Name each stored run where its job now finds its sequence (folder, family, seed and
        knobs), in one transaction; the number of rows changed. A key is content, so a sequence
        moved or renamed since resumes its rows, which would otherwise name the old folder."""
        changed = 0
        try:
            with self._db:
                for run in runs:
                    columns = RunRecord.identity_columns(run)
                    found = self._db.execute(
                        "UPDATE runs SET sequence = ?, family = ?, seed = ?, knobs = ? WHERE key = ? AND "
                        "(sequence IS NOT ? OR family IS NOT ? OR seed IS NOT ? OR knobs IS NOT ?)",
                        [*(columns[c] for c in RELABELLED), run.key, *(columns[c] for c in RELABELLED)],
                    )
                    changed += found.rowcount
        except sqlite3.Error as exc:
            raise store_error(self.path, exc) from None
        return changed

    def add(self, record: RunRecord) -> None:
        row = record.to_row()
        names = ", ".join(FIELDS)
        marks = ", ".join("?" for _ in FIELDS)
        self._write(f"INSERT OR REPLACE INTO runs ({names}) VALUES ({marks})", [row[f] for f in FIELDS])

    def by_signature(self, signature: str) -> RunRecord | None:
        """A tracked row with this decision signature, if the store has one."""
        found = self._read(
            f"SELECT {self._columns()} FROM runs WHERE signature = ? AND computed_by = key LIMIT 1",
            (signature,),
        )
        return RunRecord(**self._typed(found[0])) if found else None

    def set_meta(self, name: str, value: str) -> None:
        self._write("INSERT OR REPLACE INTO meta (name, value) VALUES (?, ?)", (name, value))

    def meta(self, name: str) -> str | None:
        found = self._read("SELECT value FROM meta WHERE name = ?", (name,))
        return None if not found else found[0][0]

    def rows(self) -> list[dict[str, Any]]:
        """Every row, ordered by key (a stable order for comparisons and exports), each value
        of its column's type."""
        return [
            self._typed(values) for values in self._read(f"SELECT {self._columns()} FROM runs ORDER BY key")
        ]

    def columns(self, names: tuple[str, ...]) -> Iterator[tuple]:
        """Every row's values of ``names`` only, typed as ``rows`` types them, one row at a time
        from SQLite's cursor: ``compare`` of a 200,000-row store holds its few columns, not
        200,000 records (1.5 GB)."""
        unknown = [n for n in names if n not in _KINDS]
        if unknown:
            raise KeyError(unknown[0])
        selected = ", ".join(f"NULL AS {n}" if n in self._missing else n for n in names)
        try:
            for values in self._db.execute(f"SELECT key, {selected} FROM runs ORDER BY key"):
                yield tuple(self._checked(values[0], dict(zip(names, values[1:], strict=True))).values())
        except sqlite3.Error as exc:
            raise store_error(self.path, exc) from None

    def records(self) -> list[RunRecord]:
        """Every run, typed, ordered by key."""
        return [RunRecord(**row) for row in self.rows()]

    def _columns(self) -> str:
        """Every record column by name; those an earlier version's store lacks, as NULL."""
        return ", ".join(f"NULL AS {f}" if f in self._missing else f for f in FIELDS)

    def _typed(self, values: tuple) -> dict[str, Any]:
        """A row whose every value has its column's type: SQLite keeps what it is given, so a
        row edited by hand (``ate_rmse_m = 'oops'``) is refused here, by key and column, not
        met later as a TypeError in a mean."""
        row = dict(zip(FIELDS, values, strict=True))
        return self._checked(row.get("key"), row)

    def _checked(self, key: object, row: dict[str, Any]) -> dict[str, Any]:
        """``row`` (some or all columns) with each value of its column's type, or refused."""
        return checked_row(
            row,
            f"{self.path}: row {str(key)[:16]}",
            "the file was changed outside depotbench: give a new output folder",
        )

    def export_csv(self, path: Path, rows: list[dict[str, Any]] | None = None) -> None:
        """The rows as CSV, each suite knob, threshold setting and tracker parameter also in
        a column of its own (``knob.actors.0.count``, ``setting.k``, ``param.window``), so a
        spreadsheet or pandas filters and plots by them without parsing JSON."""
        rows = self.rows() if rows is None else rows
        expanded = [row | _spread(row) for row in rows]
        columns = list(rows[0]) if rows else list(FIELDS)
        extra = sorted({name for row in expanded for name in row} - set(columns), key=_column_order)
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=columns + extra, lineterminator="\n")
        writer.writeheader()
        writer.writerows(expanded)
        write_text_atomic(path, buffer.getvalue())


SPREAD = {"knobs": "knob", "settings": "setting", "parameters": "param"}
"""The JSON columns whose entries the CSV also gives columns of their own, and their prefixes."""


def _spread(row: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for column, prefix in SPREAD.items():
        text = row.get(column)
        if not text:
            continue
        try:
            values = json.loads(text)
        except ValueError:
            continue  # not ours to judge here: the column itself is exported as it is
        if isinstance(values, dict):
            out |= {f"{prefix}.{name}": value for name, value in values.items()}
    return out


def _column_order(name: str) -> tuple[int, str]:
    prefix = name.split(".", 1)[0]
    return (list(SPREAD.values()).index(prefix) if prefix in SPREAD.values() else 9, name)
