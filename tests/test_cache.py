"""The stage cache only saves time: a cache that cannot be used costs a warning, never a
run or a result; its settings are read strictly (reliability probe M1, C11, D7), and it
only ever deletes its own entries."""

from __future__ import annotations

import errno
import json
import os
import time
from pathlib import Path

import pytest
from depotbench.core.cache_home import parse_bytes
from depotbench.core.output import OutputError
from depotbench.eval.cli.main import main
from depotbench.eval.run.cache import ENTRY_OVERHEAD, StageCache, content_hash

from tests.sequences import write_sequence


@pytest.fixture
def sequence(tmp_path: Path) -> Path:
    root = tmp_path / "seq"
    write_sequence(root, n=4)
    return root


def _metrics(run: Path) -> dict:
    metrics = json.loads((run / "metrics.json").read_text())
    return {k: metrics.get(k) for k in ("tracked_frames", "ate_m", "rejection", "keyframes")}


def _run(sequence: Path, out: Path) -> int:
    return main(["run", str(sequence), "-o", str(out), "--strategy", "box_rule"])


def _reference(sequence: Path, tmp_path: Path, monkeypatch) -> dict:
    with monkeypatch.context() as scoped:
        scoped.setenv("DEPOTBENCH_CACHE", "off")
        assert _run(sequence, tmp_path / "reference") == 0
    return _metrics(tmp_path / "reference")


def _one_warning(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("depotbench run: warning: the stage cache"), lines[0]
    assert "set DEPOTBENCH_CACHE_STAGES to a writable folder, or DEPOTBENCH_CACHE_STAGES=off" in lines[0]
    return lines[0]


def test_a_cache_folder_that_is_a_file_costs_one_warning_and_not_the_run(
    sequence: Path, tmp_path: Path, capsys, monkeypatch
):
    """Probe M1 `cache-dir-is-file`: the run failed on '…/detections/f08816…: Not a directory'."""
    reference = _reference(sequence, tmp_path, monkeypatch)
    capsys.readouterr()
    (tmp_path / "cachefile").write_text("x")
    monkeypatch.setenv("DEPOTBENCH_CACHE_STAGES", str(tmp_path / "cachefile"))
    assert _run(sequence, tmp_path / "run") == 0
    assert "Not a directory" in _one_warning(capsys.readouterr().err)
    assert _metrics(tmp_path / "run") == reference


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder")
def test_a_read_only_cache_costs_one_warning_and_not_the_run(
    sequence: Path, tmp_path: Path, capsys, monkeypatch
):
    """Probe M1 `rocache-run`: 'depotbench run: error: …/rocache/detections: Read-only file system'."""
    reference = _reference(sequence, tmp_path, monkeypatch)
    capsys.readouterr()
    cache = tmp_path / "ro-cache"
    cache.mkdir(mode=0o555)
    monkeypatch.setenv("DEPOTBENCH_CACHE_STAGES", str(cache))
    assert _run(sequence, tmp_path / "run") == 0
    _one_warning(capsys.readouterr().err)
    assert _metrics(tmp_path / "run") == reference


def test_a_full_cache_disk_costs_one_warning_and_not_the_run(
    sequence: Path, tmp_path: Path, capsys, monkeypatch
):
    """A full disk under the cache (as a read-only one, for root too): the write fails as
    the atomic writer reports it, and the run goes on."""
    reference = _reference(sequence, tmp_path, monkeypatch)
    capsys.readouterr()
    monkeypatch.setenv("DEPOTBENCH_CACHE_STAGES", str(tmp_path / "cache"))

    def full(path: Path, data: bytes) -> None:
        raise OutputError(f"{path}: cannot write the output ({os.strerror(errno.ENOSPC)})")

    monkeypatch.setattr("depotbench.eval.run.cache.write_bytes_atomic", full)
    assert _run(sequence, tmp_path / "run") == 0
    assert "No space left on device" in _one_warning(capsys.readouterr().err)
    assert _metrics(tmp_path / "run") == reference


def test_a_cache_that_works_says_nothing(sequence: Path, tmp_path: Path, capsys, monkeypatch):
    monkeypatch.setenv("DEPOTBENCH_CACHE_STAGES", str(tmp_path / "cache"))
    assert _run(sequence, tmp_path / "run") == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize(
    ("text", "size"),
    [("2147483648", 2 << 30), ("2GB", 2 << 30), ("2GiB", 2 << 30), ("500M", 500 << 20), ("1.5 g", 3 << 29)],
)
def test_the_cache_bound_takes_sizes_with_units(text: str, size: int, monkeypatch):
    """Probe C11: `DEPOTBENCH_CACHE_MAX_BYTES=2GB` (now ``..._STAGES_MAX_BYTES``) was a
    ValueError traceback."""
    assert parse_bytes(text, "X") == size
    monkeypatch.setenv("DEPOTBENCH_CACHE_STAGES_MAX_BYTES", text)
    assert StageCache.from_env().max_bytes == size


@pytest.mark.parametrize(
    ("variable", "value"),
    [
        ("DEPOTBENCH_CACHE_STAGES_MAX_BYTES", "lots"),
        ("DEPOTBENCH_CACHE_STAGES_MAX_BYTES", "-5"),
        ("DEPOTBENCH_CACHE", "x"),  # a folder, but relative: refused, not made in the working directory
        ("DEPOTBENCH_CACHE_STAGES", "stages"),
        ("DEPOTBENCH_CACHE_SEQUENCES", "nope"),  # refused by any command that reads a cache
    ],
)
def test_a_malformed_cache_setting_is_one_line_naming_the_variable(
    sequence: Path, tmp_path: Path, capsys, monkeypatch, variable: str, value: str
):
    monkeypatch.setenv(variable, value)
    assert _run(sequence, tmp_path / "run") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{variable}={value!r}" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_with_the_caches_off_a_vocabulary_goes_where_it_is_asked_and_nowhere_else(
    tmp_path: Path, capsys, monkeypatch
):
    """Probe D7: `DEPOTBENCH_CACHE=off` sent the vocabulary to ./off/vocabulary. Off, the
    default vocabulary is refused (tests/test_cache_command.py) and one built with -o is
    the only file written."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DEPOTBENCH_CACHE", "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    args = ["vocab", "-o", "v.txt", "--scenes", "smoke", "--frames", "2", "--branching", "2", "--levels", "1"]
    assert main(args) == 0
    assert {p.name for p in tmp_path.iterdir()} - {"xdg"} == {"v.txt"}  # xdg: Mesa's shader cache
    assert not (tmp_path / "xdg" / "depotbench").exists()
    assert (tmp_path / "v.txt").read_text().startswith("2 1 0 0\n")
    assert "v.txt" in capsys.readouterr().out


def test_eviction_never_touches_files_the_cache_did_not_write(tmp_path: Path):
    """A stage cache set by mistake to a folder of one's own: entries are ``STAGE/KEY``
    with a 32-digit hexadecimal key, and nothing else is listed, evicted or cleared."""
    home = tmp_path / "home"
    mine = ["bin/python3", "Documents/README", "Documents/" + "A" * 32, "notes", ".git/" + "a" * 32]
    for name in mine:
        (home / name).parent.mkdir(parents=True, exist_ok=True)
        (home / name).write_bytes(bytes(5000))
    cache = StageCache(home, max_bytes=2500)
    for i in range(3):
        cache.put("features", content_hash(i), bytes(1000))
    assert len(cache.entries()) == 2  # the oldest evicted, bound kept
    assert cache.size_bytes() == 2 * (1000 + ENTRY_OVERHEAD)
    assert cache.clear().entries == 2 and cache.entries() == []
    assert sorted(str(p.relative_to(home)) for p in home.rglob("*") if p.is_file()) == sorted(mine)
    with pytest.raises(ValueError, match="bad cache stage or key"):
        cache.put("features", "notes", b"x")


def test_clearing_takes_what_killed_writers_left_an_hour_ago_and_not_a_live_writers_file(tmp_path: Path):
    cache = StageCache(tmp_path / "cache")
    cache.put("features", content_hash(1), bytes(100))
    stale = tmp_path / "cache" / "features" / f".{content_hash(2)}.0a1b2c3d.tmp"
    live = tmp_path / "cache" / "features" / f".{content_hash(3)}.4e5f6a7b.tmp"
    for path in (stale, live):
        path.write_bytes(bytes(10))
    os.utime(stale, (time.time() - 3601, time.time() - 3601))
    cleared = cache.clear()
    assert (cleared.entries, cleared.bytes) == (1, 100 + ENTRY_OVERHEAD + 10)  # the entry, the stale file
    assert not stale.exists() and live.exists()
