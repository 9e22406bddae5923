"""The import graph points one way (design.md): eval -> slam, detectors, sim, scenes."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO

PACKAGES = ("core", "sim", "scenes", "slam", "detectors", "eval")
ALLOWED: dict[str, set[str]] = {
    "core": set(),
    "sim": {"core"},
    "scenes": {"core", "sim"},
    "detectors": {"core", "sim"},
    "slam": {"detectors.detection"},
    "eval": {"core", "sim", "scenes", "detectors", "slam"},
}
"""For each package, the other project modules it may import (a package allows its submodules)."""

STANDALONE = {"detectors/detection.py"}
"""Modules that import nothing from the project (slam depends on them)."""


def imported_modules(path: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    """(line, module, names) of each absolute import; names are empty for ``import m``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module, tuple(a.name for a in node.names)))
    return found


def _within(module: str, allowed: set[str]) -> bool:
    return any(module == a or module.startswith(f"{a}.") for a in allowed)


def violations(root: Path) -> list[str]:
    problems = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            allowed = set() if rel in STANDALONE else ALLOWED[package]
            for line, full, names in imported_modules(path):
                if not full.startswith("depotbench."):
                    continue
                module = full.removeprefix("depotbench.")
                top = module.split(".")[0]
                if top not in PACKAGES or top == package or _within(module, allowed):
                    continue
                # ``from depotbench.detectors import detection`` imports the allowed submodule.
                if names and all(_within(f"{module}.{n}", allowed) for n in names):
                    continue
                problems.append(f"{rel}:{line}: {package} must not import {full}")
    return sorted(problems)


def test_import_graph_points_one_way():
    assert violations(REPO) == []


def test_checker_catches_a_wrong_import(tmp_path: Path):
    for package in PACKAGES:
        (tmp_path / package).mkdir()
    (tmp_path / "slam" / "bad.py").write_text(
        "from depotbench.eval.metrics import ate\nimport depotbench.sim.camera\n"
    )
    (tmp_path / "slam" / "ok.py").write_text(
        "from depotbench.detectors.detection import Detection\nfrom depotbench.detectors import detection\n"
    )
    (tmp_path / "sim" / "bad.py").write_text("import numpy\nfrom depotbench.scenes import library\n")
    (tmp_path / "detectors" / "detection.py").write_text("import depotbench.sim.camera\n")
    (tmp_path / "detectors" / "gt.py").write_text("from depotbench.sim.sequence import Sequence\n")
    found = violations(tmp_path)
    assert found == [
        "detectors/detection.py:1: detectors must not import depotbench.sim.camera",
        "sim/bad.py:2: sim must not import depotbench.scenes",
        "slam/bad.py:1: slam must not import depotbench.eval.metrics",
        "slam/bad.py:2: slam must not import depotbench.sim.camera",
    ]


def test_sequence_reader_imports_no_mujoco_or_opengl():
    code = (
        "import sys, depotbench.sim.sequence, depotbench.eval.cli, depotbench.detectors.detection\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('mujoco', 'OpenGL', 'pyrender')]\n"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
