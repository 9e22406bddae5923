"""The package as users get it: one wheel, one namespace, its assets inside.

The wheel is built from the checkout, installed into a clean virtualenv with its declared
dependencies only, and run from a folder outside the checkout: a scenario whose cats wear
the shipped fur photograph, the default (shipped ONNX) detector, and the demo.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tests.conftest import REPO

PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())


def test_every_package_folder_is_installed_under_the_namespace():
    """A folder with an __init__.py that pyproject does not list would be left out of the
    wheel (setuptools lists packages by name when folders are mapped)."""
    config = PYPROJECT["tool"]["setuptools"]
    mapped = config["package-dir"]
    listed = set(config["packages"])
    found = set()
    for package, folder in mapped.items():
        for init in (REPO / folder).rglob("__init__.py"):
            if "__pycache__" in init.parts:
                continue
            rel = init.parent.relative_to(REPO / folder).parts
            found.add(".".join((package, *rel)))
    assert found == listed
    assert all(name == "depotbench" or name.startswith("depotbench.") for name in listed)


def _uv() -> str | None:
    here = Path(sys.executable).parent / "uv"
    return str(here) if here.exists() else shutil.which("uv")


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A virtualenv holding the wheel and its dependencies, nothing of the checkout."""
    uv = _uv()
    if uv is None:
        pytest.fail("uv is needed to install the wheel (make installs it into the virtualenv)")
    root = tmp_path_factory.mktemp("wheel")
    # built from a copy: setuptools leaves build/ and *.egg-info in the folder it builds
    source = root / "source"
    skip = shutil.ignore_patterns(".git", ".venv", "build", "runs", "*.egg-info", "__pycache__", ".*_cache")
    shutil.copytree(REPO, source, ignore=skip)
    subprocess.run([uv, "build", "--wheel", "--out-dir", str(root / "dist"), str(source)], check=True,
                   capture_output=True)  # fmt: skip
    (wheel,) = (root / "dist").glob("depotbench-*.whl")
    venv = root / "venv"
    subprocess.run([uv, "venv", "--python", sys.executable, str(venv)], check=True, capture_output=True)
    # Compiled at install, as pip does by default (uv does not): the runs below import from a
    # venv they may not write to (PYTHONDONTWRITEBYTECODE), and each process compiled every
    # module it imported from source again (the demo's test 66 s, 56 s with the bytecode).
    python = str(venv / "bin" / "python")
    install = [uv, "pip", "install", "--compile-bytecode", "--python", python, str(wheel)]
    subprocess.run(install, check=True, capture_output=True)
    return venv


def _run(venv: Path, cwd: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env |= {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run(
        [str(venv / "bin" / args[0]), *args[1:]], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=timeout,
    )  # fmt: skip


def test_the_wheel_installs_only_the_namespace(installed: Path, tmp_path: Path):
    shown = _run(installed, tmp_path, "python", "-m", "pip", "show", "-f", "depotbench")
    if shown.returncode != 0:  # uv's virtualenvs hold no pip: read the record pip reads
        record = next(installed.glob("lib/python*/site-packages/depotbench-*.dist-info/RECORD"))
        files = [line.split(",")[0] for line in record.read_text().splitlines() if line]
    else:
        files = shown.stdout.split("Files:", 1)[1].split()
    outside = [
        f for f in files if not f.startswith(("depotbench/", "depotbench-")) and "bin/depotbench" not in f
    ]
    assert files and outside == []
    assert any(f.endswith("assets/models/yolox_nano/yolox_nano.onnx") for f in files)
    assert any(f.endswith("assets/textures/cat_fur.png") for f in files)
    site = next(installed.glob("lib/python*/site-packages"))
    ours = {
        p.name
        for p in site.iterdir()
        if p.name.lower().startswith(("sim", "eval", "scenes", "slam", "detec"))
    }
    assert ours == set()  # no generic top-level package


@pytest.mark.render
def test_the_installed_wheel_generates_detects_and_runs_the_demo(installed: Path, tmp_path: Path):
    """What broke for a user with the wheel: the cats' fur photograph and the default model
    were not in it, so generate dog_and_cat_roaming and detect-eval failed."""
    generated = _run(installed, tmp_path, "depotbench", "generate", "dog_and_cat_roaming", "-o", "cats",
                     "--frames", "3")  # fmt: skip
    assert generated.returncode == 0, generated.stderr
    report = tmp_path / "detect.json"
    detected = _run(installed, tmp_path, "depotbench", "detect-eval", "cats", "-o", str(report))
    assert detected.returncode == 0, detected.stderr
    assert json.loads(report.read_text())  # the shipped model ran
    demo = _run(installed, tmp_path, "depotbench", "demo", "-o", "demo", timeout=600)
    assert demo.returncode == 0, demo.stdout[-2000:] + demo.stderr[-2000:]
    assert "all budgets held" in demo.stdout and (tmp_path / "demo" / "report" / "index.html").is_file()
    imported = _run(
        installed,
        tmp_path,
        "python",
        "-c",
        "import depotbench, depotbench.eval.cli.main; print(depotbench.__file__)",
    )
    assert imported.returncode == 0 and str(REPO) not in imported.stdout
    # The Python API from the wheel, on the sequence generated above (the README's lines).
    api = (
        "import depotbench\n"
        "record = depotbench.run('cats', strategy='box_rule', settings={'box_dilation_px': 8})\n"
        "print(type(record).__name__, record.strategy, record.frames)\n"
    )
    ran = _run(installed, tmp_path, "python", "-c", api)
    assert ran.returncode == 0, ran.stderr[-2000:]
    assert ran.stdout.split() == ["RunRecord", "box_rule", "3"]
