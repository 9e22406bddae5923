"""A full disk is one line naming the output, exit 2, and nothing half-written: no
staging folder, no lock, no empty output, no warning after the line (reliability probe C6).

The commands run in a child process whose files may not grow past a few kilobytes
(``RLIMIT_FSIZE``): its writes fail as on a full disk (EFBIG instead of ENOSPC), through the
real writers. The child writes no bytecode: a ``.pyc`` cut short by the cap would break every
later import of that module.
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main

from tests.conftest import REPO

pytestmark = pytest.mark.render


def capped(args: list[str], cwd: Path, limit_bytes: int) -> subprocess.CompletedProcess:
    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "DEPOTBENCH_CACHE": "off", "MUJOCO_GL": "egl"}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    return subprocess.run(
        [sys.executable, "-m", "depotbench.eval.cli", *args],
        cwd=cwd,
        env=env,
        preexec_fn=limit,
        capture_output=True,
        text=True,
        timeout=300,
    )


def one_line(result: subprocess.CompletedProcess, *needles: str) -> None:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*") if p.name != ".depotbench.json")


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("full") / "seq"
    assert main(["generate", "smoke", "-o", str(root), "--frames", "4"]) == 0
    return root


def test_generate_on_a_full_disk(tmp_path: Path):
    result = capped(["generate", "smoke", "-o", "g", "--frames", "3"], tmp_path, 8000)
    one_line(result, "depotbench generate: error: g: cannot write the output (File too large)")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_run_on_a_full_disk(sequence: Path, tmp_path: Path):
    result = capped(["run", str(sequence), "-o", "r", "--strategy", "box_rule"], tmp_path, 1000)
    one_line(result, "depotbench run: error: r: cannot write the output (File too large)")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_suite_on_a_full_disk_leaves_no_staging_folder_lock_or_empty_suite(tmp_path: Path):
    """`diskfull-suite-generate`: a 56-line traceback, two "leaked semaphore" warnings, and a
    `.tinysuite-0002.partial-*` folder and lock left by the worker killed meanwhile."""
    (tmp_path / "s.yaml").write_text("suite: tinysuite\nbase: smoke\noverrides: {frames: 3}\nseeds: [1, 2]\n")
    result = capped(["generate", "s.yaml", "-o", "suite", "--workers", "2"], tmp_path, 8000)
    one_line(result, "suite/tinysuite-000", "cannot write the output (File too large)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.yaml"]
    assert hidden(tmp_path) == []


def test_a_sweep_whose_suite_fills_the_disk_keeps_nothing_half_written(tmp_path: Path):
    (tmp_path / "s.yaml").write_text("suite: tinysuite\nbase: smoke\noverrides: {frames: 3}\nseeds: [1]\n")
    (tmp_path / "w.yaml").write_text("sweep: w\nsuite: s.yaml\nstrategies: [none]\n")
    result = capped(["sweep", "w.yaml", "-o", "sw", "--workers", "1"], tmp_path, 8000)
    one_line(result, "cannot write the output (File too large)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.yaml", "w.yaml"]
    assert hidden(tmp_path) == []
