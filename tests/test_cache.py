"""The stage cache only saves time: a cache that cannot be used costs a warning, never a
run or a result; its settings are read strictly (reliability probe M1, C11, D7)."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest
from depotbench.core.cache_home import parse_bytes
from depotbench.core.output import OutputError
from depotbench.eval.cli.main import main
from depotbench.eval.run.cache import StageCache

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
    monkeypatch.setenv("DEPOTBENCH_CACHE", "off")
    assert _run(sequence, tmp_path / "reference") == 0
    monkeypatch.delenv("DEPOTBENCH_CACHE")
    return _metrics(tmp_path / "reference")


def _one_warning(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("depotbench run: warning: the stage cache"), lines[0]
    assert "DEPOTBENCH_CACHE_DIR" in lines[0] and "DEPOTBENCH_CACHE=off" in lines[0]
    return lines[0]


def test_a_cache_folder_that_is_a_file_costs_one_warning_and_not_the_run(
    sequence: Path, tmp_path: Path, capsys, monkeypatch
):
    """Probe M1 `cache-dir-is-file`: the run failed on '…/detections/f08816…: Not a directory'."""
    reference = _reference(sequence, tmp_path, monkeypatch)
    capsys.readouterr()
    (tmp_path / "cachefile").write_text("x")
    monkeypatch.setenv("DEPOTBENCH_CACHE_DIR", str(tmp_path / "cachefile"))
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
    monkeypatch.setenv("DEPOTBENCH_CACHE_DIR", str(cache))
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
    monkeypatch.setenv("DEPOTBENCH_CACHE_DIR", str(tmp_path / "cache"))

    def full(path: Path, data: bytes) -> None:
        raise OutputError(f"{path}: cannot write the output ({os.strerror(errno.ENOSPC)})")

    monkeypatch.setattr("depotbench.eval.run.cache.write_bytes_atomic", full)
    assert _run(sequence, tmp_path / "run") == 0
    assert "No space left on device" in _one_warning(capsys.readouterr().err)
    assert _metrics(tmp_path / "run") == reference


def test_a_cache_that_works_says_nothing(sequence: Path, tmp_path: Path, capsys, monkeypatch):
    monkeypatch.setenv("DEPOTBENCH_CACHE_DIR", str(tmp_path / "cache"))
    assert _run(sequence, tmp_path / "run") == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize(
    ("text", "size"),
    [("2147483648", 2 << 30), ("2GB", 2 << 30), ("2GiB", 2 << 30), ("500M", 500 << 20), ("1.5 g", 3 << 29)],
)
def test_the_cache_bound_takes_sizes_with_units(text: str, size: int, monkeypatch):
    """Probe C11: `DEPOTBENCH_CACHE_MAX_BYTES=2GB` was a ValueError traceback."""
    assert parse_bytes(text, "X") == size
    monkeypatch.setenv("DEPOTBENCH_CACHE_MAX_BYTES", text)
    assert StageCache().max_bytes == size


@pytest.mark.parametrize(
    ("variable", "value"),
    [
        ("DEPOTBENCH_CACHE_MAX_BYTES", "lots"),
        ("DEPOTBENCH_CACHE_MAX_BYTES", "-5"),
        ("DEPOTBENCH_CACHE", "/x"),
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


def test_turning_the_stage_cache_off_keeps_the_vocabulary_in_the_cache_folder(
    tmp_path: Path, capsys, monkeypatch
):
    """Probe D7: `DEPOTBENCH_CACHE=off` sent the vocabulary to ./off/vocabulary."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DEPOTBENCH_CACHE", "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    args = ["vocab", "--scenes", "smoke", "--frames", "2", "--branching", "2", "--levels", "1"]
    assert main(args) == 0
    assert not (tmp_path / "off").exists()
    built = list((tmp_path / "xdg" / "depotbench" / "vocabulary").glob("orb-k2-L1-*.txt"))
    assert len(built) == 1 and str(built[0]) in capsys.readouterr().out
