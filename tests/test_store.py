"""The results database: refused files are left as they were, and every SQLite failure
(a lock, a full disk, a read-only place, a row edited by hand) is one line naming the
file and the cause (reliability probe D11, M2, C7, C8)."""

from __future__ import annotations

import hashlib
import shutil
import sqlite3
from dataclasses import replace
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.metrics.record import RunIdentity, RunRecord
from depotbench.eval.sweep.store import ResultStore, StoreError

from tests.sequences import write_sequence


@pytest.fixture(scope="module")
def swept(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished one-row sweep, copied by the tests that change it."""
    root = tmp_path_factory.mktemp("swept")
    write_sequence(root / "seq", n=4)
    (root / "x.yaml").write_text("sweep: x\nsequences: [seq]\nstrategies: [none]\n")
    assert main(["sweep", str(root / "x.yaml"), "-o", str(root / "sw")]) == 0
    return root


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_line(capsys, *needles: str) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def _record(key: str) -> RunRecord:
    run = RunIdentity(key, "f", "seq", "fp", "builtin", "groundtruth", "none")
    failed = RunRecord.failed(run, "", 4, 0.5, "0")
    return replace(failed, failure=None, tracked_fraction=1.0, keyframes=1, ate_rmse_m=0.01, ate_mean_m=0.01)


def _sweep(root: Path, out: Path) -> int:
    return main(["sweep", str(root / "x.yaml"), "-o", str(out)])


@pytest.mark.parametrize("content", ["wrong schema", "not sqlite"])
def test_a_refused_database_is_left_byte_for_byte_as_it_was(swept: Path, tmp_path: Path, capsys, content):
    """Probe D11: the refused file had been switched to WAL and given a meta table."""
    out = tmp_path / "sw-x"
    out.mkdir()
    shutil.copyfile(swept / "sw" / ".depotbench.json", out / ".depotbench.json")  # a sweep folder of ours
    database = out / "results.sqlite"
    if content == "wrong schema":
        db = sqlite3.connect(database)
        db.execute("create table runs (key text)")
        db.commit()
        db.close()
    else:
        database.write_text("these are my notes\n")
    before = _sha(database)
    assert _sweep(swept, out) == 2
    _one_line(capsys, str(database), "columns" if content == "wrong schema" else "not an SQLite file")
    assert _sha(database) == before
    assert sorted(p.name for p in out.iterdir()) == [".depotbench.json", "results.sqlite"]


def test_a_database_locked_by_another_program_is_one_line(swept: Path, tmp_path: Path, capsys, monkeypatch):
    """Probe C7: a traceback after 30 s (`sqlite3.OperationalError: database is locked`)."""
    monkeypatch.setattr("depotbench.eval.sweep.store.LOCK_WAIT_S", 0.2)
    shutil.copytree(swept / "sw", tmp_path / "sw")
    holder = sqlite3.connect(tmp_path / "sw" / "results.sqlite", isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        assert _sweep(swept, tmp_path / "sw") == 2
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    _one_line(capsys, "results.sqlite", "another program holds it locked")


def test_a_full_disk_while_rows_are_written_is_one_line_and_keeps_the_rows(tmp_path: Path):
    """Probe C6 `diskfull-sweep-96k`: `sqlite3.OperationalError: database or disk is full`
    in store.add. SQLite's own page limit fails the insert as a full disk does."""
    store = ResultStore(tmp_path / "r.sqlite")
    pages = store._db.execute("PRAGMA page_count").fetchone()[0]
    store._db.execute(f"PRAGMA max_page_count = {pages + 1}")
    added = 0
    with pytest.raises(StoreError, match=r"r.sqlite: the disk is full; the rows written so far are kept"):
        for i in range(1000):
            store.add(_record(f"k{i:04d}" + "x" * 500))
            added += 1
    assert len(store.keys()) == added > 0


def test_a_row_edited_by_hand_is_refused_by_its_key_and_column(swept: Path, tmp_path: Path, capsys):
    """Probe C8: `ate_rmse_m='oops'` gave a TypeError traceback in improvement_rate."""
    shutil.copytree(swept / "sw", tmp_path / "sw")
    db = sqlite3.connect(tmp_path / "sw" / "results.sqlite")
    db.execute("update runs set ate_rmse_m = 'oops'")
    db.commit()
    db.close()
    assert _sweep(swept, tmp_path / "sw") == 2
    _one_line(capsys, "results.sqlite: row ", "ate_rmse_m is 'oops', not a number")


def test_reading_a_database_leaves_it_and_its_folder_unchanged(swept: Path, tmp_path: Path):
    """Probe M2 `report-sweep-readonly`: opening switched on WAL and created tables, so a
    database in a read-only place could not be read at all."""
    shutil.copytree(swept / "sw", tmp_path / "sw")
    database = tmp_path / "sw" / "results.sqlite"
    before = (_sha(database), sorted(p.name for p in database.parent.iterdir()))
    with ResultStore(database, readonly=True) as store:
        assert len(store.rows()) == 1
        with pytest.raises(StoreError, match="read-only"):
            store.add(_record("new"))
    assert (_sha(database), sorted(p.name for p in database.parent.iterdir())) == before


def test_column_types_come_from_the_record(tmp_path: Path):
    """The fingerprint was a REAL column: SQLite turns text that reads as a number into one."""
    store = ResultStore(tmp_path / "r.sqlite")
    record = _record("k")
    store.add(RunRecord(**{**record.to_row(), "sequence_fingerprint": "1234567890"}))
    assert store.rows()[0]["sequence_fingerprint"] == "1234567890"


def test_counts_a_0_3_15_database_kept_as_reals_are_read_as_integers(tmp_path: Path):
    """0.3.15 made relocalized_frames a REAL column: its whole-number values still read."""
    store = ResultStore(tmp_path / "r.sqlite")
    store.add(_record("k"))
    store._db.execute("UPDATE runs SET relocalized_frames = 0.0, frames = 4.0")
    store._db.commit()
    row = store.rows()[0]
    assert row["relocalized_frames"] == 0 and type(row["frames"]) is int
    store._db.execute("UPDATE runs SET frames = 4.5")
    store._db.commit()
    with pytest.raises(StoreError, match="frames is 4.5, not an integer"):
        store.rows()


def _version_4_store(path: Path) -> None:
    """A results database as record version 4 wrote it: no ate_median_m column."""
    store = ResultStore(path)
    store.add(_record("old"))
    store.close()
    with sqlite3.connect(path) as db:
        db.execute("ALTER TABLE runs DROP COLUMN ate_median_m")
        db.execute("UPDATE runs SET record_version = 4")


def test_an_earlier_versions_store_is_read_and_resumed_with_the_new_column_empty(tmp_path: Path):
    """A baseline kept from before the median ATE (record version 4) still serves compare and
    check --baseline, and a sweep folder of it resumes: the column is added, its rows keep
    it empty. A store of columns no version had is still refused."""
    database = tmp_path / "v4.sqlite"
    _version_4_store(database)
    with ResultStore(database, readonly=True) as store:
        (row,) = store.rows()
    assert row["key"] == "old" and row["ate_median_m"] is None and row["ate_rmse_m"] == 0.01
    with ResultStore(database) as store:
        store.add(replace(_record("new"), ate_median_m=0.008))
        assert {r["key"]: r["ate_median_m"] for r in store.rows()} == {"old": None, "new": 0.008}
    with ResultStore(database, readonly=True) as store:  # the added column's order is its own
        assert len(store.rows()) == 2
    with sqlite3.connect(database) as db:
        db.execute("ALTER TABLE runs ADD COLUMN colour TEXT")
    with pytest.raises(StoreError, match="other columns than record version"):
        ResultStore(database, readonly=True)
