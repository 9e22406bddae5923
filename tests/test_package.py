"""The package as users get it: one wheel, one namespace, its assets and licences inside.

The sdist is built from the checkout and the wheel from the sdist, as a package index's user
builds them, without a warning; the wheel is installed into a clean virtualenv with its
declared dependencies only, and run from a folder outside the checkout: a scenario whose cats
wear the shipped fur photograph, the default (shipped ONNX) detector, and the demo.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from dataclasses import dataclass
from fnmatch import fnmatch
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
    data_only = listed - found  # folders of data (and example scripts), listed for setuptools: the next test
    assert found <= listed and all("." in name for name in data_only)
    assert all(name == "depotbench" or name.startswith("depotbench.") for name in listed)


DATA_ONLY_UNSHIPPED = {"assets/readme"}
"""Folders of files under a package folder that the wheel leaves out: the README's pictures
(in the sdist through docs/images)."""


def test_every_file_of_the_package_folders_is_package_data_of_a_listed_package():
    """include-package-data is off, so a file no pattern names is left out of the wheel; and
    setuptools warns once per folder of data that is not a listed package (Python imports it
    as a namespace package), so each pattern names files of its own folder only."""
    config = PYPROJECT["tool"]["setuptools"]
    mapped = config["package-dir"]
    listed = set(config["packages"])
    data = config["package-data"]
    assert set(data) <= listed
    assert all("/" not in pattern for patterns in data.values() for pattern in patterns)
    unshipped = []
    for package, folder in mapped.items():
        for path in (REPO / folder).rglob("*"):
            if not path.is_file() or "__pycache__" in path.parts or path.suffix == ".py":
                continue
            if path.parent.relative_to(REPO).as_posix() in DATA_ONLY_UNSHIPPED:
                continue
            owner = ".".join((package, *path.parent.relative_to(REPO / folder).parts))
            if owner not in listed or not any(fnmatch(path.name, p) for p in data.get(owner, ())):
                unshipped.append(path.relative_to(REPO).as_posix())
    assert unshipped == []


def test_the_metadata_names_its_licences_and_pypis_classifiers():
    """PEP 639: an SPDX expression and the licence files; setuptools refuses a "License ::"
    classifier beside the expression, and PyPI refuses a classifier not in its list."""
    from trove_classifiers import classifiers as known

    project = PYPROJECT["project"]
    assert project["license"] == "MIT"
    assert "MIT License" in (REPO / "LICENSE").read_text()
    assert "Apache License" in (REPO / "assets/models/yolox_nano/LICENSE").read_text()
    assert "Willow Garage" in (REPO / "assets/orb/LICENSE").read_text()
    assert all((REPO / name).is_file() for name in project["license-files"])
    assert set(project["classifiers"]) <= known
    assert not [c for c in project["classifiers"] if c.startswith("License ::")]
    lowest = project["requires-python"].removeprefix(">=")
    assert f"Programming Language :: Python :: {lowest}" in project["classifiers"]


def test_export_rosbag_without_the_ros_extra_says_how_to_install(tmp_path: Path):
    """rosbags serves export-rosbag alone and is the extra [ros]: without it the command
    says so in one line and exits non-zero, and the other commands do not need it."""
    from tests.sequences import write_sequence

    write_sequence(tmp_path / "seq", n=2)
    bag = tmp_path / "bag"
    code = (
        "import sys\n"
        "sys.modules['rosbags'] = None  # as if not installed: importing it raises ModuleNotFoundError\n"
        "from depotbench.eval.cli.main import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    env = os.environ | {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    run = [sys.executable, "-c", code, "export-rosbag", str(tmp_path / "seq"), "-o", str(bag)]
    done = subprocess.run(run, capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode != 0 and done.stdout == ""
    assert done.stderr.strip() == (
        "depotbench export-rosbag: error: export-rosbag needs the ros extra: pip install 'depotbench[ros]'"
    )
    assert not bag.exists()
    listed = subprocess.run([*run[:3], "scenarios"], capture_output=True, text=True, env=env, timeout=120)
    assert listed.returncode == 0 and "walking_xyz" in listed.stdout, listed.stderr
    extras = PYPROJECT["project"]["optional-dependencies"]
    assert not [d for d in PYPROJECT["project"]["dependencies"] if d.startswith("rosbags")]
    assert [d for d in extras["ros"] if d.startswith("rosbags")] and "depotbench[ros]" in extras["dev"]


def _uv() -> str | None:
    here = Path(sys.executable).parent / "uv"
    return str(here) if here.exists() else shutil.which("uv")


@dataclass(frozen=True)
class Built:
    sdist: Path
    wheel: Path
    log: str
    """What the build backend printed, both builds."""


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Built:
    """The sdist built from the checkout, and the wheel built from the sdist (uv build's default,
    as pip builds a package it gets as source)."""
    uv = _uv()
    if uv is None:
        pytest.fail("uv is needed to build and install the wheel (make installs it into the virtualenv)")
    root = tmp_path_factory.mktemp("wheel")
    # built from a copy: setuptools leaves build/ and *.egg-info in the folder it builds
    source = root / "source"
    skip = shutil.ignore_patterns(".git", ".venv", "build", "runs", "*.egg-info", "__pycache__", ".*_cache")
    shutil.copytree(REPO, source, ignore=skip, symlinks=True)
    # setuptools notes each skipped byte-compilation as a warning when this is set
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    done = subprocess.run([uv, "build", "--out-dir", str(root / "dist"), str(source)], check=True,
                          capture_output=True, text=True, env=env)  # fmt: skip
    (sdist,) = (root / "dist").glob("depotbench-*.tar.gz")
    (wheel,) = (root / "dist").glob("depotbench-*.whl")
    return Built(sdist, wheel, done.stdout + done.stderr)


def test_the_build_prints_no_warning(built: Built):
    """There were 16 warning lines: 8 data folders not listed as packages, each twice."""
    warnings = [line for line in built.log.splitlines() if "warn" in line.lower()]
    assert warnings == []


def test_the_wheel_and_sdist_carry_every_licence(built: Built):
    with zipfile.ZipFile(built.wheel) as wheel:
        names = wheel.namelist()
        metadata = wheel.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    licences = [n.split(".dist-info/licenses/", 1)[1] for n in names if ".dist-info/licenses/" in n]
    assert sorted(licences) == ["LICENSE", "assets/models/yolox_nano/LICENSE", "assets/orb/LICENSE"]
    assert "depotbench/assets/models/yolox_nano/LICENSE" in names  # and beside the model
    assert {"depotbench/assets/orb/LICENSE", "depotbench/assets/orb/bit_pattern_31.txt"} <= set(names)
    assert "License-Expression: MIT" in metadata
    assert "Classifier: Topic :: Scientific/Engineering" in metadata
    with tarfile.open(built.sdist) as sdist:
        top = sdist.getnames()[0].split("/")[0]
        held = {name.removeprefix(top + "/") for name in sdist.getnames()}
    shipped = {
        "assets/models/yolox_nano/LICENSE",
        "assets/models/yolox_nano/PROVENANCE.md",
        "assets/orb/LICENSE",
    }
    assert {"LICENSE", *shipped} <= held


def test_the_sdist_holds_what_its_tests_read(built: Built):
    """The tests read docs/ (its examples run, its tables are held to the code), benchmarks/
    and the programs in tests/: every file git tracks there is in the sdist (a link to a
    folder, docs/images, as the folder's files)."""
    tracked = subprocess.run(["git", "ls-files", "docs", "benchmarks", "tests", ".ci"], cwd=REPO,
                             capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
    if not tracked:
        pytest.skip("not a git checkout: nothing to compare the sdist with")
    with tarfile.open(built.sdist) as sdist:
        top = sdist.getnames()[0].split("/")[0]
        held = {name.removeprefix(top + "/") for name in sdist.getnames()}
    files = [name for name in tracked if not (REPO / name).is_symlink()]
    assert [name for name in files if name not in held] == []
    assert "mkdocs.yml" in held and any(name.startswith("docs/images/") for name in held)


@pytest.mark.slow
def test_tests_run_from_the_unpacked_sdist(built: Built, tmp_path: Path):
    """Two test files that read docs/ and pyproject.toml, run inside the unpacked sdist."""
    with tarfile.open(built.sdist) as sdist:
        sdist.extractall(tmp_path, filter="data")
    (unpacked,) = tmp_path.iterdir()
    tests = [
        "tests/test_placeholders.py",
        "tests/test_package.py::test_every_package_folder_is_installed_under_the_namespace",
    ]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    pytest_ = [sys.executable, "-m", "pytest", "-q", "-p", "no:xdist", "-p", "no:cacheprovider"]
    done = subprocess.run([*pytest_, *tests], cwd=unpacked, capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stdout[-3000:]
    assert "4 passed" in done.stdout


@pytest.fixture(scope="module")
def installed(built: Built, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A virtualenv holding the wheel and its dependencies, nothing of the checkout."""
    uv = _uv()
    assert uv is not None
    root = tmp_path_factory.mktemp("venv")
    wheel = built.wheel
    venv = root / "venv"
    subprocess.run([uv, "venv", "--python", sys.executable, str(venv)], check=True, capture_output=True)
    # Compiled at install, as pip does by default (uv does not): the runs below import from a
    # venv they may not write to (PYTHONDONTWRITEBYTECODE), and each process compiled every
    # module it imported from source again (the demo's test 66 s, 56 s with the bytecode).
    python = str(venv / "bin" / "python")
    install = [uv, "pip", "install", "--compile-bytecode", "--python", python, str(wheel)]
    subprocess.run(install, check=True, capture_output=True)
    return venv


@pytest.fixture(scope="module")
def installed_alone(built: Built, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A virtualenv holding the wheel alone (``--no-deps``, no bytecode): what the wheel puts
    where, in 2 s where the full install above takes 30 s (it compiles every dependency)."""
    uv = _uv()
    assert uv is not None
    venv = tmp_path_factory.mktemp("alone") / "venv"
    subprocess.run([uv, "venv", "--python", sys.executable, str(venv)], check=True, capture_output=True)
    install = [uv, "pip", "install", "--no-deps", "--python", str(venv / "bin" / "python"), str(built.wheel)]
    subprocess.run(install, check=True, capture_output=True)
    return venv


def _run(venv: Path, cwd: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env |= {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run(
        [str(venv / "bin" / args[0]), *args[1:]], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=timeout,
    )  # fmt: skip


def test_the_wheel_installs_only_the_namespace(installed_alone: Path, tmp_path: Path):
    installed = installed_alone
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


@pytest.mark.slow  # 170 s on 2 cores: the default suite runs the demo in-process (test_cli.py)
@pytest.mark.render  # and installs the wheel alone (test_the_wheel_installs_only_the_namespace)
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
