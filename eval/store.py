"""The results database: SQLite, one row per run, keyed by the job's content hash.

Each row is written in its own transaction by the one process that owns the
store (workers return rows; they never write), so a process killed at any moment
leaves every finished row and no partial one (SQLite's write-ahead log rolls an
unfinished transaction back). Rerunning a sweep skips the keys already present.
"""

from __future__ import annotations

import csv
import io
import sqlite3
from pathlib import Path
from typing import Any

from eval.record import FIELDS, RECORD_VERSION, RunRecord
from sim.errors import InputError
from sim.output import write_text_atomic

_TYPES = {
    "frames": "INTEGER",
    "lost_frames": "INTEGER",
    "keyframes": "INTEGER",
    "moving_inliers": "INTEGER",
    "record_version": "INTEGER",
}
_TEXT = {
    "key",
    "family",
    "sequence",
    "tracker",
    "detector",
    "strategy",
    "settings",
    "bench_version",
    "signature",
    "computed_by",
}


def _column(name: str) -> str:
    kind = "TEXT" if name in _TEXT else _TYPES.get(name, "REAL")
    return f"{name} {kind}{' PRIMARY KEY' if name == 'key' else ''}"


class ResultStore:
    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self._db = sqlite3.connect(path, timeout=30.0)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute(f"CREATE TABLE IF NOT EXISTS runs ({', '.join(_column(f) for f in FIELDS)})")
            self._db.execute("CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value TEXT)")
            self._db.commit()
            columns = [row[1] for row in self._db.execute("PRAGMA table_info(runs)")]
        except sqlite3.DatabaseError as exc:
            raise InputError(f"{path}: not a depotbench results database ({exc})") from None
        if tuple(columns) != FIELDS:
            raise InputError(
                f"{path}: its runs table has other columns than record version {RECORD_VERSION}; "
                "give a new output folder"
            )

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def keys(self) -> set[str]:
        return {row[0] for row in self._db.execute("SELECT key FROM runs")}

    def add(self, record: RunRecord) -> None:
        row = record.to_row()
        names = ", ".join(FIELDS)
        marks = ", ".join("?" for _ in FIELDS)
        with self._db:  # one transaction: the row is there whole, or not at all
            self._db.execute(
                f"INSERT OR REPLACE INTO runs ({names}) VALUES ({marks})", [row[f] for f in FIELDS]
            )

    def by_signature(self, signature: str) -> RunRecord | None:
        """A tracked row with this decision signature, if the store has one."""
        cursor = self._db.execute(
            f"SELECT {', '.join(FIELDS)} FROM runs WHERE signature = ? AND computed_by = key LIMIT 1",
            (signature,),
        )
        row = cursor.fetchone()
        return None if row is None else RunRecord(**dict(zip(FIELDS, row, strict=True)))

    def set_meta(self, name: str, value: str) -> None:
        with self._db:
            self._db.execute("INSERT OR REPLACE INTO meta (name, value) VALUES (?, ?)", (name, value))

    def meta(self, name: str) -> str | None:
        row = self._db.execute("SELECT value FROM meta WHERE name = ?", (name,)).fetchone()
        return None if row is None else row[0]

    def rows(self) -> list[dict[str, Any]]:
        """Every row, ordered by key (a stable order for comparisons and exports)."""
        cursor = self._db.execute(f"SELECT {', '.join(FIELDS)} FROM runs ORDER BY key")
        return [dict(zip(FIELDS, values, strict=True)) for values in cursor]

    def export_csv(self, path: Path, rows: list[dict[str, Any]] | None = None) -> None:
        rows = self.rows() if rows is None else rows
        buffer = io.StringIO()
        columns = list(rows[0]) if rows else list(FIELDS)
        writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        write_text_atomic(path, buffer.getvalue())
