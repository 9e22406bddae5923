"""The import graph points one way, at every level.

Between root folders: ``eval -> slam, detectors, scenes, sim -> core`` (slam takes only the
plain detection type, the camera, errors, logs, the kernels' switch ``core.jit`` and the
shipped files' paths ``core.assets``, for ORB's point pairs). Inside
``eval``: its subpackages in the order of the pipeline, each importing only those before
it; inside ``slam``: ORB-SLAM's parts in floors, tracking above local mapping and
relocalisation above the matcher and the optimiser.
Everywhere: no import cycle between modules (imports inside functions count: a deferred
import is still a dependency), and nothing outside the command line imports it. The package's
face (``depotbench/``: ``import depotbench`` and its API) may import anything, and no part
imports it.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from tests.conftest import REPO

PACKAGES = ("core", "sim", "scenes", "slam", "detectors", "eval")
ALLOWED: dict[str, set[str]] = {
    "core": set(),
    "sim": {"core"},
    "scenes": {"core", "sim"},
    "detectors": {"core", "sim"},
    "slam": {"detectors.detection", "core.camera", "core.errors", "core.logs", "core.jit", "core.assets"},
    "eval": {"core", "sim", "scenes", "detectors", "slam"},
}
"""For each root folder, the other project modules it may import (a package allows its submodules)."""

STANDALONE = {"detectors/detection.py", "core/camera.py", "core/errors.py", "core/logs.py", "core/assets.py"}
"""Modules that import nothing from the project (slam depends on them)."""

EVAL_FLOORS = (
    "metrics",
    "trackers",
    "run",
    "detection",
    "export",
    "sweep",
    "gates",
    "report",
    "validate",
    "pytest_plugin",
    "cli",
)
"""eval's parts, bottom to top: each may import its own floor and those below."""

CLI = "depotbench.eval.cli"

SLAM_FLOORS = (
    ("types", "config", "geometry"),
    ("features", "map", "matcher", "optimize", "bundle", "pose", "rejection", "kernels"),
    ("local_mapping", "mapping_clock", "relocalisation", "dense_map"),
    ("tracking",),
    ("system",),
)
"""slam's modules, bottom to top, as ORB-SLAM layers them: each may import its own floor and
those below (plain types and geometry; features, matching, the map and the optimisers, each
beside the kernels that compile its loops; local mapping with the clock that paces it,
relocalisation and the dense map (it reads the rejection's decisions); the tracking state
machine; the system's face)."""


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


def _modules(root: Path) -> dict[str, Path]:
    """Every module of the root folders by its installed name (``depotbench.eval.run.harness``)."""
    out = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root / package).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(("depotbench", package, *parts))] = path
    return out


def _targets(module: str, names: tuple[str, ...], known: dict[str, Path]) -> list[str]:
    """The project modules an import statement loads: ``from a.b import c`` is a.b.c when c is
    a module, else a.b."""
    subs = [f"{module}.{n}" for n in names if f"{module}.{n}" in known]
    if subs and len(subs) == len(names):
        return subs
    while module and module not in known:
        module = module.rpartition(".")[0]
    return [module, *subs] if module else subs


def _floor(module: str) -> int | None:
    parts = module.split(".")
    if parts[:2] != ["depotbench", "eval"] or len(parts) < 3:
        return None
    return EVAL_FLOORS.index(parts[2]) if parts[2] in EVAL_FLOORS else None


def violations(root: Path) -> list[str]:
    known = _modules(root)
    problems = []
    edges: dict[str, set[str]] = {m: set() for m in known}
    for name, path in known.items():
        package = name.split(".")[1]
        rel = path.relative_to(root).as_posix()
        allowed = set() if rel in STANDALONE else ALLOWED[package]
        for line, full, names in imported_modules(path):
            if not full.startswith("depotbench.") and full != "depotbench":
                continue
            module = full.removeprefix("depotbench.")
            top = module.split(".")[0]
            if full == "depotbench" or top == "api":
                problems.append(f"{rel}:{line}: {package} must not import the package's face ({full})")
            for target in _targets(full, names, known):
                if target != name:
                    edges[name].add(target)
                if target.startswith(CLI) and not name.startswith(CLI):
                    problems.append(f"{rel}:{line}: only the command line imports {target}")
                mine, theirs = _floor(name), _floor(target)
                if mine is not None and theirs is not None and theirs > mine:
                    problems.append(
                        f"{rel}:{line}: eval.{EVAL_FLOORS[mine]} must not import {target} (above it)"
                    )
            if top not in PACKAGES or (top == package and rel not in STANDALONE) or _within(module, allowed):
                continue
            # ``from depotbench.detectors import detection`` imports the allowed submodule.
            if names and all(_within(f"{module}.{n}", allowed) for n in names):
                continue
            problems.append(f"{rel}:{line}: {package} must not import {full}")
    problems += [f"import cycle: {' <-> '.join(c)}" for c in cycles(edges)]
    return sorted(set(problems))


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module."""
    names = sorted(edges)
    index = {n: i for i, n in enumerate(names)}
    pairs = [(index[a], index[b]) for a, targets in edges.items() for b in targets if b in index]
    if not pairs:
        return []
    rows, cols = zip(*pairs, strict=True)
    graph = csr_matrix((np.ones(len(pairs)), (rows, cols)), shape=(len(names), len(names)))
    count, labels = connected_components(graph, directed=True, connection="strong")
    groups = [[names[i] for i in np.flatnonzero(labels == k)] for k in range(count)]
    return [g for g in groups if len(g) > 1]


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
    for floor in ("metrics", "sweep", "cli"):
        (tmp_path / "eval" / floor).mkdir()
        (tmp_path / "eval" / floor / "__init__.py").write_text("")
    (tmp_path / "eval" / "metrics" / "up.py").write_text("from depotbench.eval.sweep import engine\n")
    (tmp_path / "eval" / "sweep" / "engine.py").write_text(
        "def f():\n    from depotbench.eval.metrics.up import x\n    from depotbench.eval.cli import args\n"
    )
    (tmp_path / "eval" / "cli" / "args.py").write_text("")
    (tmp_path / "eval" / "metrics" / "face.py").write_text(
        "import depotbench\nfrom depotbench.api import run\n"
    )
    (tmp_path / "core" / "camera.py").write_text("from depotbench.core.errors import InputError\n")
    (tmp_path / "slam" / "camera.py").write_text("from depotbench.core.camera import Intrinsics\n")
    found = violations(tmp_path)
    assert found == [
        "core/camera.py:1: core must not import depotbench.core.errors",
        "detectors/detection.py:1: detectors must not import depotbench.sim.camera",
        "eval/metrics/face.py:1: eval must not import the package's face (depotbench)",
        "eval/metrics/face.py:2: eval must not import the package's face (depotbench.api)",
        "eval/metrics/up.py:1: eval.metrics must not import depotbench.eval.sweep.engine (above it)",
        "eval/sweep/engine.py:3: eval.sweep must not import depotbench.eval.cli.args (above it)",
        "eval/sweep/engine.py:3: only the command line imports depotbench.eval.cli.args",
        "import cycle: depotbench.eval.metrics.up <-> depotbench.eval.sweep.engine",
        "sim/bad.py:2: sim must not import depotbench.scenes",
        "slam/bad.py:1: slam must not import depotbench.eval.metrics",
        "slam/bad.py:2: slam must not import depotbench.sim.camera",
    ]


def test_sequence_reader_imports_no_mujoco_or_opengl():
    code = (
        "import sys, depotbench.sim.sequence, depotbench.eval.cli.main, depotbench.detectors.detection\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('mujoco', 'OpenGL', 'pyrender')]\n"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


MUJOCO_FOLDERS = (*PACKAGES, "depotbench", "tests", "benchmarks", "examples")
"""Where Python that may import MuJoCo lives (the package, its tests, benchmarks and examples)."""


def direct_mujoco_imports(root: Path) -> list[str]:
    """Modules that import MuJoCo before ``depotbench.sim.mujoco_env`` has (or without it):
    MuJoCo picks its GL backend from ``MUJOCO_GL`` when first imported, and only mujoco_env
    sets it (to egl) first. One test module importing ``mujoco`` at its top made every test
    of its pytest worker render through GLFW when the shell had not set the variable."""
    problems = []
    for folder in MUJOCO_FOLDERS:
        for path in sorted((root / folder).rglob("*.py")) if (root / folder).is_dir() else []:
            if path.relative_to(root).as_posix() == "sim/mujoco_env.py":
                continue
            found = imported_modules(path)
            direct = [line for line, module, _ in found if module.split(".")[0] == "mujoco"]
            chosen = [line for line, module, _ in found if module == "depotbench.sim.mujoco_env"]
            if direct and (not chosen or min(chosen) > min(direct)):
                problems.append(f"{path.relative_to(root).as_posix()}:{min(direct)}: imports mujoco directly")
    return problems


def test_mujoco_is_imported_only_after_its_gl_backend_is_chosen(tmp_path: Path):
    assert direct_mujoco_imports(REPO) == []
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_bad.py").write_text("import numpy\nimport mujoco\n")
    (tmp_path / "tests" / "test_good.py").write_text(
        "from depotbench.sim.mujoco_env import mujoco\nfrom mujoco import gl_context\n"
    )
    assert direct_mujoco_imports(tmp_path) == ["tests/test_bad.py:2: imports mujoco directly"]


def _slam_floor(module: str) -> int | None:
    parts = module.split(".")
    if parts[:2] != ["depotbench", "slam"] or len(parts) < 3:
        return None
    return next((i for i, floor in enumerate(SLAM_FLOORS) if parts[2] in floor), None)


def slam_floor_violations(root: Path) -> list[str]:
    """slam modules that import a module on a floor above their own, and slam modules on no
    floor (a new module must be given one)."""
    known = _modules(root)
    problems = []
    for name, path in known.items():
        if not name.startswith("depotbench.slam."):
            continue
        rel = path.relative_to(root).as_posix()
        mine = _slam_floor(name)
        if mine is None:
            problems.append(f"{rel}: on no floor of SLAM_FLOORS")
            continue
        short = name.removeprefix("depotbench.")
        for line, full, names in imported_modules(path):
            for target in _targets(full, names, known):
                theirs = _slam_floor(target)
                if theirs is not None and theirs > mine:
                    problems.append(f"{rel}:{line}: {short} must not import {target} (above it)")
    return sorted(set(problems))


def test_slam_modules_import_only_their_floor_and_below():
    assert slam_floor_violations(REPO) == []


def test_slam_floor_checker_catches_an_import_from_above(tmp_path: Path):
    for package in PACKAGES:
        (tmp_path / package).mkdir()
    (tmp_path / "slam" / "__init__.py").write_text("")
    (tmp_path / "slam" / "matcher.py").write_text("from depotbench.slam.tracking import Tracking\n")
    (tmp_path / "slam" / "tracking.py").write_text(
        "from depotbench.slam import matcher, system\nfrom depotbench.slam.map import Map\n"
    )
    (tmp_path / "slam" / "map.py").write_text("def f():\n    from depotbench.slam.optimize import x\n")
    (tmp_path / "slam" / "optimize.py").write_text("")
    (tmp_path / "slam" / "system.py").write_text("")
    (tmp_path / "slam" / "loose.py").write_text("")
    assert slam_floor_violations(tmp_path) == [
        "slam/loose.py: on no floor of SLAM_FLOORS",
        "slam/matcher.py:1: slam.matcher must not import depotbench.slam.tracking (above it)",
        "slam/tracking.py:1: slam.tracking must not import depotbench.slam.system (above it)",
    ]
