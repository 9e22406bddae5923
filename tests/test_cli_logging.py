"""The command line's conventions of issue 54 (item 3): ``-v``/``-vv`` through ``logging`` on
stderr, ``--json`` on every command that reports something (one object on stdout, nothing
else there), ``--version`` after a command, and an option error in the command's own name.

Each ``--json`` is checked against what the command wrote, read by something other than the
code that wrote it (OpenCV for the PNG, ``rosbags`` for the bag, the files on disk)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from depotbench.eval.cli.main import build_parser, main

from tests.sequences import write_sequence

PROGRAM = [sys.executable, "-m", "depotbench.eval.cli"]


def cli(capsys, *argv: str | Path) -> tuple[int, str, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own exits
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def as_json(capsys, *argv: str | Path) -> tuple[dict, str]:
    """The command's one JSON object (the whole of stdout) and its stderr."""
    code, out, err = cli(capsys, *argv, "--json")
    assert code == 0, err
    return json.loads(out), err


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("logging") / "seq"
    write_sequence(root, n=5, seed=5401)  # a seed of its own: no other test fills its cache keys
    return root


# --version and option errors after a command


def test_version_after_a_command_prints_it_and_exits_0():
    from importlib import metadata

    done = subprocess.run([*PROGRAM, "run", "--version"], capture_output=True, text=True)
    assert (done.returncode, done.stderr) == (0, "")
    assert done.stdout.strip() == f"depotbench {metadata.version('depotbench')}"


@pytest.mark.parametrize(
    "argv",
    [["run", "--bogus"], ["run", "seq", "-o", "out", "--bogus"], ["run", "--bogus", "seq"]],
    ids=["alone", "after-the-arguments", "before-a-missing-one"],
)
def test_an_unknown_option_is_refused_in_the_commands_own_name(argv, capsys):
    """argparse passed it up to the top parser ("depotbench: error"), and a missing SEQUENCE
    hid it."""
    code, out, err = cli(capsys, *argv)
    assert code == 2 and out == ""
    assert err.strip().splitlines() == [
        "depotbench run: error: unrecognized arguments: --bogus (see depotbench run --help)"
    ]


def test_a_command_left_incomplete_still_names_what_is_missing(capsys):
    code, _, err = cli(capsys, "run", "-v")
    assert code == 2
    assert err.startswith("depotbench run: error: the following arguments are required: sequence")


def test_every_command_that_reports_something_takes_json():
    """Every command (and each action of one with actions, such as cache info) but those that
    print a script (completion) takes --json."""

    def leaves(parser, name):
        found = [a for a in parser._actions if a.choices and hasattr(a, "_name_parser_map")]
        if not found:
            return [(name, parser)]
        return [leaf for n, p in found[0].choices.items() for leaf in leaves(p, f"{name} {n}".strip())]

    without = {
        name for name, parser in leaves(build_parser(), "") if "--json" not in parser._option_string_actions
    }
    assert without == {"completion"}


# -v and -vv


def test_vv_shows_cache_hits_and_misses_with_their_keys(sequence: Path, tmp_path: Path, capsys):
    code, first_out, first = cli(capsys, "run", sequence, "-o", tmp_path / "a", "-vv")
    assert code == 0, first
    code, second_out, second = cli(capsys, "-v", "run", sequence, "-o", tmp_path / "b", "-v")
    assert code == 0, second
    hits = re.findall(r"depotbench run: debug: \[cache\] stage cache hit: features ([0-9a-f]{32})", second)
    assert len(hits) == 1, second
    key = hits[0]
    assert f"features {key}" in first  # the first run looked up the same entry (a miss, then stored)
    stored = [p for p in Path(os.environ["DEPOTBENCH_CACHE"]).rglob(key) if p.is_file()]
    assert len(stored) == 1 and stored[0].parent.name == "features"
    # -v: where the time went; nothing of it on stdout, which holds the run's summary alone
    assert re.search(r"detail: \[eval\.run\.harness\] seq builtin none: tracking 5 frames took \d", second)
    assert "debug:" not in first_out + second_out and "detail:" not in first_out + second_out
    assert first_out.startswith("builtin none on ")
    code, _, plain = cli(capsys, "run", sequence, "-o", tmp_path / "c")
    assert code == 0 and "debug:" not in plain and "detail:" not in plain


def test_v_shows_an_external_programs_command_line(sequence: Path, tmp_path: Path, capsys):
    """The program's argv as a shell would take it (shlex), with its folder and timeout."""
    program = tmp_path / "slam.py"
    program.write_text("import sys\nopen(sys.argv[2], 'w').write('')\n")
    template = f"{sys.executable} {program} {{sequence}} {{trajectory}}"
    code, out, err = cli(
        capsys, "run", sequence, "-o", tmp_path / "run", "--slam", "cmd", "--command", template, "-v"
    )
    lines = [line for line in err.splitlines() if ": running " in line]
    assert len(lines) == 1, err
    assert lines[0].startswith("depotbench run: detail: [eval.trackers.external] ")
    assert f"{sys.executable} {program} " in lines[0] and "(timeout 3600 s)" in lines[0]


# --json on each command: one object on stdout, matching what was written


def test_preview_json(sequence: Path, tmp_path: Path, capsys):
    import cv2

    result, _ = as_json(capsys, "preview", sequence, "--frames", "0", "3", "-o", tmp_path / "p.png")
    assert set(result) == {"png", "frames", "width", "height", "seconds"}
    image = cv2.imread(result["png"])
    assert (result["height"], result["width"]) == image.shape[:2]
    assert result["frames"] == [0, 3]


def test_export_dataset_json(sequence: Path, tmp_path: Path, capsys):
    out = tmp_path / "ds"
    result, _ = as_json(capsys, "export-dataset", sequence, "-o", out, "--val-fraction", "0")
    assert result["dataset"] == str(out)
    assert result == {**json.loads((out / "splits.json").read_text()), "dataset": str(out)} | {
        "seconds": result["seconds"]
    }
    for split in ("train", "val"):
        images = list((out / "images" / split).glob("*")) if (out / "images" / split).exists() else []
        assert result["counts"][split]["images"] == len(images)
    assert result["counts"]["train"]["images"] == 5


def test_export_rosbag_json(sequence: Path, tmp_path: Path, capsys):
    pytest.importorskip("rosbags")
    from rosbags.highlevel import AnyReader

    result, _ = as_json(capsys, "export-rosbag", sequence, "-o", tmp_path / "bag")
    assert {"bag", "storage", "frames", "messages", "bytes", "topics", "seconds"} <= set(result)
    with AnyReader([Path(result["bag"])]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert {t["topic"]: t["count"] for t in result["topics"]} == counts
    assert result["messages"] == sum(counts.values()) and result["frames"] == 5


def test_report_json(sequence: Path, tmp_path: Path, capsys):
    assert cli(capsys, "run", sequence, "-o", tmp_path / "run")[0] == 0
    result, _ = as_json(capsys, "report", tmp_path / "run", "-o", tmp_path / "page")
    assert set(result) == {"source", "page", "page_bytes", "recording", "left_out", "seconds"}
    page = Path(result["page"])
    assert page.parent == tmp_path / "page" and result["page_bytes"] == page.stat().st_size
    assert result["recording"] is None


@pytest.mark.render
def test_generate_json(tmp_path: Path, capsys):
    out = tmp_path / "g"
    result, err = as_json(capsys, "generate", "smoke", "-o", out, "--frames", "2", "--seed", "4")
    assert set(result) == {"kind", "name", "seed", "frames", "sequence", "seconds"}
    assert (result["kind"], result["name"], result["seed"], result["frames"]) == ("scenario", "smoke", 4, 2)
    assert result["sequence"] == str(out)
    assert len(list((out / "rgb").glob("*.png"))) == 2


@pytest.mark.slow
@pytest.mark.render
def test_generate_a_suite_json_keeps_status_lines_on_stderr(tmp_path: Path, capsys):
    (tmp_path / "suite.yaml").write_text("suite: tiny\nbase: smoke\noverrides: {frames: 2}\nseeds: [1]\n")
    result, err = as_json(capsys, "generate", tmp_path / "suite.yaml", "-o", tmp_path / "s", "--workers", "1")
    index = json.loads((tmp_path / "s" / "index.json").read_text())
    assert (result["kind"], result["suite"]) == ("suite", "tiny")
    assert result["sequences"] == index["sequences"] and len(result["sequences"]) == 1
    assert "index:" in err  # the suite's status line, moved off stdout


@pytest.mark.slow
@pytest.mark.render
def test_vocab_json(tmp_path: Path, capsys):
    """Words counted in the DBoW2 text itself: a node line is 'parent is_leaf descriptor weight'."""
    args = ["--scenes", "smoke", "--frames", "2", "--branching", "2", "--levels", "1", "--workers", "1"]
    result, _ = as_json(capsys, "vocab", "-o", tmp_path / "v.txt", *args)
    lines = (tmp_path / "v.txt").read_text().splitlines()[1:]
    assert result["words"] == sum(line.split()[1] == "1" for line in lines)
    assert (result["branching"], result["levels"], result["scenes"]) == (2, 1, ["smoke"])


@pytest.mark.slow
@pytest.mark.render
def test_demo_json(tmp_path: Path, capsys):
    out = tmp_path / "demo"
    result, err = as_json(capsys, "demo", "-o", out, "--workers", "1")
    assert {"report", "results_csv", "junit", "runs", "passed", "failures", "seconds"} <= set(result)
    rows = (out / "results.csv").read_text().strip().splitlines()
    assert result["runs"] == len(rows) - 1 and Path(result["report"]).is_file()
    assert "1/4 the demo suite" in err


def test_cache_clear_json(capsys):
    """What clear removed, as the folder holds it before (the session's private caches)."""
    root = Path(os.environ["DEPOTBENCH_CACHE"])
    entries = [p for p in (root / "stages").rglob("*") if p.is_file()] if (root / "stages").exists() else []
    result, _ = as_json(capsys, "cache", "clear", "--stage")
    assert set(result) == {"caches", "freed_bytes"} and set(result["caches"]) == {"stages"}
    stages = result["caches"]["stages"]
    assert stages["entries"] == len(entries) and stages["bytes"] == result["freed_bytes"]
    assert not [p for p in (root / "stages").rglob("*") if p.is_file()]


@pytest.mark.slow
def test_vv_reaches_a_sweeps_worker_processes(tmp_path: Path):
    """A sweep looks its stages up in spawned workers, whose logger stayed at Python's
    WARNING: -vv said nothing of them. Through the real program, --json on stdout alone."""
    for name, seed in (("a", 1), ("b", 2)):
        write_sequence(tmp_path / name, n=4, seed=5410 + seed)
    (tmp_path / "w.yaml").write_text("sweep: w\nsequences: [a, b]\nstrategies: [none]\n")
    done = subprocess.run(
        [*PROGRAM, "sweep", str(tmp_path / "w.yaml"), "-o", str(tmp_path / "sw"), "--workers", "2", "-vv"]
        + ["--json"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    json.loads(done.stdout)
    assert "detail: [core.executors] started a pool of 2 spawned worker processes" in done.stderr
    workers = set(
        re.findall(r"depotbench worker (\d+): debug: \[cache\] stage cache miss: features", done.stderr)
    )
    assert len(workers) >= 1 and str(os.getpid()) not in workers
