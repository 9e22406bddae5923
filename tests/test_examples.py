"""Shipped examples by name: every sweep spec, gate file, suite and example tracker is listed
by ``depotbench examples``, found by name by sweep, check, generate and validate (a path that
exists wins), and copied into a folder where it runs as it did beside its siblings."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from depotbench.core.examples import Kind, companions, examples, find
from depotbench.eval.cli.main import main
from depotbench.eval.validate import kind_of
from depotbench.scenes import library

from tests.conftest import REPO

SHELVES = {
    "assets/sweeps": "*.yaml",
    "assets/gates": "*.yaml",
    "scenes/suites": "*.yaml",
    "assets/examples/external": "*.py",
    "assets/examples": "*.txt",
    "assets/benchmarks": "*.yaml",
}
"""Where the checkout keeps what the wheel ships as examples (pyproject's package data)."""


def cli(capsys, *args: str | Path) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_error_line(err: str, *needles: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def shipped_files() -> dict[str, Path]:
    return {p.stem: p for folder, pattern in SHELVES.items() for p in sorted((REPO / folder).glob(pattern))}


def test_examples_lists_every_shipped_file_with_its_kind_and_description(capsys):
    code, out, _ = cli(capsys, "examples", "--json")
    assert code == 0
    listed = {entry["name"]: entry for entry in json.loads(out)}
    files = shipped_files()
    assert set(listed) == set(files)
    for name, path in files.items():
        if path.suffix in (".py", ".txt"):
            assert listed[name]["kind"] == {".py": "example tracker", ".txt": "trajectory"}[path.suffix]
            continue
        data = yaml.safe_load(path.read_text())
        assert listed[name]["kind"] == kind_of(path), name  # as validate reads the kind
        first = " ".join(data["description"].split()).split(". ")[0]
        assert listed[name]["description"].rstrip(".") == first.rstrip("."), name
    code, out, _ = cli(capsys, "examples")
    assert code == 0
    names = {line.split()[2] if line.startswith(("sweep", "gate", "example")) else line.split()[1]
             for line in out.splitlines() if line.strip() and not line.startswith("run one")}  # fmt: skip
    assert names == set(files)


def test_names_are_unique_and_no_suite_shadows_a_library_scenario():
    stems = [p.stem for folder, pattern in SHELVES.items() for p in (REPO / folder).glob(pattern)]
    assert len(stems) == len(set(stems))
    assert not [s for s in stems if "." in s]  # a name with a suffix would be read as a path
    suites = {e.name for e in examples().values() if e.kind is Kind.SUITE}
    assert suites and not suites & set(library.names())  # generate takes both kinds by name


def test_every_shelf_ships_in_the_wheel():
    """A shelf the wheel leaves out would list nothing after pip install (pyproject's package data)."""
    import tomllib

    from depotbench.core.examples import SHELVES

    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    data, packages = config["package-data"], config["packages"]
    for shelf in SHELVES:
        folder = f"{shelf.package}.{shelf.folder.replace('/', '.')}"  # a data folder listed as a package
        shipped = (
            f"{shelf.folder}/{shelf.pattern}" in data.get(shelf.package, [])
            or shelf.pattern in data.get(folder, [])
            or (shelf.pattern == "*.py" and folder in packages)  # modules of a listed package
        )
        assert shipped, shelf


def test_sweep_and_check_find_a_shipped_spec_by_name(capsys, tmp_path: Path):
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "mine.txt").write_text("a user's file")
    # The spec is found and validated, then the folder (not depotbench's) is refused.
    code, _, err = cli(capsys, "sweep", "smallest", "-o", taken)
    one_error_line(err, "depotbench sweep: error:", str(taken))
    assert code == 2 and "smallest" not in err.split(str(taken))[0].split("error:")[1]
    junit = tmp_path / "gates.xml"
    junit.write_text("<kept/>")
    code, _, err = cli(capsys, "check", "walking-ci", "--junit", junit, "-o", tmp_path / "c")
    one_error_line(err, "depotbench check: error:", str(junit))
    assert code == 2 and junit.read_text() == "<kept/>" and not (tmp_path / "c").exists()


def test_validate_and_generate_take_names(capsys, tmp_path: Path):
    code, out, err = cli(capsys, "validate", "smallest", "walking-ci", "demo", "walking4")
    assert code == 0, err
    assert [line.split(": ok: ")[1].split(",")[0] for line in out.splitlines()] == [
        "sweep spec",
        "gate file",
        "suite",
        "suite",
    ]
    # generate reads the shipped suite by name: its per-scenario options are refused as a suite's.
    code, _, err = cli(capsys, "generate", "demo", "-o", tmp_path / "seqs", "--frames", "3")
    one_error_line(err, "apply to one scenario; set them in the suite")
    assert code == 2 and not (tmp_path / "seqs").exists()


def test_eval_takes_the_shipped_trajectories_by_name(capsys):
    """The pair evo's test data holds: by name it is the same comparison as by path (evo
    1.38.1 gives ATE RMSE 0.013473 m on it, as tests/test_cli.py holds)."""
    code, by_name, err = cli(capsys, "eval", "fr1_xyz_groundtruth", "fr1_xyz_rgbdslam", "--json")
    assert code == 0, err
    files = [REPO / "assets" / "examples" / f"fr1_xyz_{which}.txt" for which in ("groundtruth", "rgbdslam")]
    code, by_path, _ = cli(capsys, "eval", *files, "--json")
    assert code == 0 and json.loads(by_name) == json.loads(by_path)
    assert round(json.loads(by_name)["ate_m"]["rmse"], 6) == 0.013473


def test_a_path_that_exists_wins_over_a_name(capsys, tmp_path: Path, monkeypatch):
    own = yaml.safe_load(find("smallest", Kind.SWEEP).read_text())
    own["sweep"] = "mine"
    own["suite"] = "walking4"  # the shipped suite by name: this file has no sibling
    monkeypatch.chdir(tmp_path)
    Path("smallest").write_text(yaml.safe_dump(own))
    assert find("smallest", Kind.SWEEP) == Path("smallest")
    code, out, err = cli(capsys, "validate", "smallest")
    assert code == 0, err
    assert "'mine'" in out


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (("generate", "dem", "-o", "x"), ("no library scenario named 'dem', nor a shipped suite", "demo?")),
        (("generate", "walkng_xyz", "-o", "x"), ("did you mean walking_xyz",)),
        (("sweep", "smalest", "-o", "x"), ("smalest", "did you mean smallest?")),
        (("sweep", "walking-ci", "-o", "x"), ("a shipped gate file, not a sweep spec", "smallest")),
        (("check", "walkin-ci"), ("no such file, nor a shipped gate file", "did you mean walking-ci?")),
        (("check", "nothing-like-it"), ("known: walking-ci",)),
        (("examples", "copy", "smalest"), ("no shipped example", "did you mean smallest?")),
    ],
)
def test_an_unknown_name_is_one_line_with_the_close_names(capsys, tmp_path, monkeypatch, argv, needles):
    monkeypatch.chdir(tmp_path)
    code, out, err = cli(capsys, *argv)
    assert code == 2 and out == ""
    one_error_line(err, *needles)
    assert list(tmp_path.iterdir()) == []


def test_copy_brings_the_suite_and_the_copy_reads_its_own_files(capsys, tmp_path: Path, monkeypatch):
    folder = tmp_path / "mine"
    code, out, err = cli(capsys, "examples", "copy", "smallest", folder)
    assert code == 0, err
    assert sorted(p.name for p in folder.iterdir()) == ["smallest.yaml", "walking4.yaml"]
    assert (folder / "smallest.yaml").read_bytes() == find("smallest", Kind.SWEEP).read_bytes()
    monkeypatch.chdir(tmp_path)  # elsewhere: relative names inside resolve from the copy's folder
    code, out, err = cli(capsys, "validate", folder / "smallest.yaml")
    assert code == 0, err
    # The copy reads its own suite file, not the shipped one.
    (folder / "walking4.yaml").write_text((folder / "walking4.yaml").read_text() + "bogus_field: 1\n")
    code, out, err = cli(capsys, "validate", folder / "smallest.yaml")
    assert code == 2 and str(folder / "walking4.yaml") in err and "bogus_field" in err


def test_copy_refuses_to_overwrite_and_writes_nothing_without_the_flag(capsys, tmp_path: Path):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "walking4.yaml").write_text("my own suite\n")
    code, _, err = cli(capsys, "examples", "copy", "smallest", folder)
    one_error_line(err, str(folder / "walking4.yaml"), "exists; --overwrite replaces it")
    assert code == 2 and [p.name for p in folder.iterdir()] == ["walking4.yaml"]
    assert (folder / "walking4.yaml").read_text() == "my own suite\n"
    code, out, err = cli(capsys, "examples", "copy", "smallest", folder, "--overwrite", "--json")
    assert code == 0, err
    assert sorted(Path(p).name for p in json.loads(out)) == ["smallest.yaml", "walking4.yaml"]
    assert (folder / "walking4.yaml").read_bytes() == find("walking4", Kind.SUITE).read_bytes()


def test_copy_all_gives_every_example_and_each_validates_in_its_new_folder(capsys, tmp_path, monkeypatch):
    folder = tmp_path / "examples"
    code, out, err = cli(capsys, "examples", "copy", "--all", folder, "--json")
    assert code == 0, err
    locks = sorted(p.name for p in folder.iterdir() if p.name.endswith(".lock.json"))
    assert sorted(p.stem for p in folder.iterdir() if p.name not in locks) == sorted(shipped_files())
    assert locks == sorted(f"{p.stem}.lock.json" for p in (REPO / "assets" / "benchmarks").glob("*.yaml"))
    for program in folder.glob("*.py"):
        assert os.access(program, os.X_OK), program  # a sweep runs it by its path
    monkeypatch.chdir(tmp_path)
    specs = sorted(str(p) for p in folder.glob("*.yaml"))
    code, out, err = cli(capsys, "validate", *specs)
    assert code == 0, err
    assert len(out.splitlines()) == len(specs)


def test_companions_are_the_relative_files_beside_a_spec(tmp_path: Path):
    """What copy brings with a spec: its suite file and the suite's base scenario file, a
    tracker's program and settings template; not a name, an absolute path or a file outside."""
    folder = tmp_path / "spec"
    (folder / "tools").mkdir(parents=True)
    for name in ("base.yaml", "tools/prog.sh", "settings.j2", "other.yaml"):
        (folder / name).write_text("x: 1\n")
    (tmp_path / "outside.yaml").write_text("x: 1\n")
    (folder / "suite.yaml").write_text("suite: s\nbase: base.yaml\n")
    spec = {
        "sweep": "s",
        "suite": "suite.yaml",
        "sequences": ["../outside.yaml", str(folder / "other.yaml"), "walking4"],
        "trackers": [{"name": "p", "command": "./tools/prog.sh {sequence}", "settings": "settings.j2"}],
    }
    (folder / "spec.yaml").write_text(yaml.safe_dump(spec))
    found = {p.relative_to(folder).as_posix() for p in companions(folder / "spec.yaml")}
    assert found == {"suite.yaml", "base.yaml", "tools/prog.sh", "settings.j2"}


@pytest.mark.slow
def test_from_the_wheel_examples_copy_and_names_work(wheel_venv: Path, tmp_path: Path):
    """A user with the wheel alone (a fresh uv venv, its declared dependencies only): the
    shipped spec and gate file by name and a copy of the spec validate, and the copied
    example tracker is a program."""
    installed = wheel_venv
    copied = _run(installed, tmp_path, "depotbench", "examples", "copy", "smallest", "mine")
    assert copied.returncode == 0, copied.stderr
    by_name = _run(
        installed, tmp_path, "depotbench", "validate", "smallest", "walking-ci", "mine/smallest.yaml"
    )
    assert by_name.returncode == 0, by_name.stderr
    assert by_name.stdout.count(": ok: ") == 3
    tracker = _run(installed, tmp_path, "depotbench", "examples", "copy", "my_slam", "trackers")
    assert tracker.returncode == 0 and os.access(tmp_path / "trackers" / "my_slam.py", os.X_OK)


@pytest.mark.slow
def test_from_the_wheel_the_shipped_sweep_runs_by_name_and_a_copied_gate_file_checks(
    wheel_venv: Path, tmp_path: Path
):
    """The issue's user, end to end from an empty folder: depotbench sweep smallest (32 runs),
    then the gate file copied out and checked there (its suite named, not beside it)."""
    swept = _run(wheel_venv, tmp_path, "depotbench", "sweep", "smallest", "-o", "s", "--workers", "2")
    assert swept.returncode == 0, swept.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / "s" / "results.csv").open()))
    assert len(rows) == 4 * (1 + 4 + 3)  # four sequences x none, four k, three epsilon_px
    assert json.loads((tmp_path / "s" / "summary.json").read_text())["best"]
    copied = _run(wheel_venv, tmp_path, "depotbench", "examples", "copy", "walking-ci", "gates")
    assert copied.returncode == 0 and sorted(p.name for p in (tmp_path / "gates").iterdir()) == [
        "walking-ci.yaml"
    ]
    checked = _run(wheel_venv, tmp_path, "depotbench", "check", "gates/walking-ci.yaml", "-o", "c", "--json")
    assert checked.returncode in (0, 1), checked.stderr[-2000:]  # 1: a budget failed on this machine
    verdicts = json.loads(checked.stdout)
    assert verdicts["passed"] == (checked.returncode == 0) and verdicts["results"]


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _wheel_venv(tmp_path_factory.mktemp("wheel"))


def test_the_python_api_takes_names_too(tmp_path: Path):
    from depotbench.core.errors import InputError

    import depotbench

    with pytest.raises(InputError, match="did you mean smallest"):
        depotbench.sweep("smalest", tmp_path / "s")
    with pytest.raises(InputError, match="known: walking-ci"):
        depotbench.check("no-such-gates", tmp_path / "c")
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "mine.txt").write_text("a user's file")
    with pytest.raises(InputError, match="taken"):  # found and validated, then the folder refused
        depotbench.sweep("smallest", taken)
    assert not (tmp_path / "s").exists() and not (tmp_path / "c").exists()


def _wheel_venv(root: Path) -> Path:
    """The checkout's wheel in a fresh uv virtualenv with its declared dependencies only."""
    uv = Path(sys.executable).parent / "uv"
    uv_ = str(uv) if uv.exists() else shutil.which("uv")
    assert uv_ is not None, "uv builds and installs the wheel (make installs it into the venv)"
    source = root / "source"  # setuptools leaves build/ and *.egg-info where it builds
    skip = shutil.ignore_patterns(".git", ".venv", "build", "runs", "*.egg-info", "__pycache__", ".*_cache")
    shutil.copytree(REPO, source, ignore=skip)
    subprocess.run([uv_, "build", "--wheel", "--out-dir", str(root / "dist"), str(source)], check=True,
                   capture_output=True)  # fmt: skip
    (wheel,) = (root / "dist").glob("depotbench-*.whl")
    venv = root / "venv"
    subprocess.run([uv_, "venv", "--python", sys.executable, str(venv)], check=True, capture_output=True)
    python = str(venv / "bin" / "python")
    subprocess.run([uv_, "pip", "install", "--python", python, str(wheel)], check=True, capture_output=True)
    return venv


def _run(venv: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["MUJOCO_GL"] = os.environ.get("MUJOCO_GL", "egl")
    command = [str(venv / "bin" / args[0]), *args[1:]]
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_a_specs_suite_is_a_file_beside_it_before_a_shipped_suites_name(capsys, tmp_path: Path):
    spec = tmp_path / "spec.yaml"
    spec.write_text("sweep: s\nsuite: walking4\nstrategies: [none]\n")
    code, out, err = cli(capsys, "validate", spec)
    assert code == 0, err  # the shipped suite
    (tmp_path / "walking4").write_text("suite: mine\nbase: walking_static\nbogus_field: 1\n")
    code, out, err = cli(capsys, "validate", spec)
    assert code == 2 and str(tmp_path / "walking4") in err and "bogus_field" in err
    spec.write_text("sweep: s\nsuite: walkng4\nstrategies: [none]\n")
    code, out, err = cli(capsys, "validate", spec)
    one_error_line(err, "suite:", "walkng4 is not a file, nor a shipped suite's name")
