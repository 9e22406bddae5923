"""The command line's conventions (issue 39): --version, -v/-q, a description and examples in
every command's help, shell completion read back by bash and zsh themselves, --json on the
commands that report results, validate for every file kind, and a --help that imports no
NumPy (its speed is measured by benchmarks/cli_help.py, not asserted here)."""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest
from depotbench.eval.cli import choices
from depotbench.eval.cli.conventions import USAGE, verbosity
from depotbench.eval.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parent.parent


def _commands() -> dict:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "verb")
    return sub.choices


def test_choices_named_for_help_equal_their_sources():
    from depotbench.eval.metrics.accuracy import DeltaUnit
    from depotbench.eval.metrics.alignment import Alignment
    from depotbench.eval.metrics.trajectory import DEFAULT_MAX_DIFF_S
    from depotbench.eval.run.harness import STRATEGY_CHOICES
    from depotbench.eval.trackers.vocabulary import TRAINING_SCENES, VocabularySpec

    assert choices.STRATEGIES == STRATEGY_CHOICES
    assert tuple(a.value for a in Alignment) == choices.ALIGNMENTS
    assert tuple(u.value for u in DeltaUnit) == choices.DELTA_UNITS
    assert choices.MAX_DIFF_S == DEFAULT_MAX_DIFF_S
    assert choices.TRAINING_SCENES == TRAINING_SCENES
    spec = VocabularySpec()
    assert {k: getattr(spec, k) for k in choices.VOCABULARY_DEFAULTS} == choices.VOCABULARY_DEFAULTS


def test_help_imports_no_numpy():
    """--help builds every parser; none may import NumPy, SciPy or OpenCV (0.1 s, not 0.5)."""
    code = (
        "import sys\nfrom depotbench.eval.cli.main import build_parser\n"
        "build_parser().format_help()\n"
        "print(sorted(m for m in ('numpy', 'scipy', 'cv2', 'mujoco') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"depotbench {metadata.version('depotbench')}"


def test_every_command_has_a_description_and_examples_that_parse():
    """Each example in a command's help is parsed by the parser itself: an example naming an
    option that does not exist, or a wrong choice, fails here."""
    commands = _commands()
    assert set(commands) == set(USAGE)
    for name, parser in commands.items():
        text = parser.format_help()
        assert USAGE[name].description.split()[0] in text
        assert "examples:" in text
        for example in USAGE[name].examples:
            words = shlex.split(example.split(" > ")[0].split("  #")[0])
            assert words[:2] == ["depotbench", name]
            build_parser().parse_args(words[1:])  # exits 2 on a bad example


def test_verbosity_before_or_after_the_command():
    parser = build_parser()
    assert parser.parse_args(["-q", "scenarios"]).quiet
    assert parser.parse_args(["scenarios", "-q"]).quiet
    assert verbosity(parser.parse_args(["-vv", "scenarios"])) == 2
    assert verbosity(parser.parse_args(["scenarios", "-v"])) == 1
    assert verbosity(parser.parse_args(["-v", "scenarios", "-v"])) == 2
    assert verbosity(parser.parse_args(["-q", "scenarios"])) == -1
    assert not parser.parse_args(["-v", "scenarios"]).quiet


def test_quiet_prints_nothing_but_errors(tmp_path):
    """-q through the real program: a successful command prints nothing at all; a failing one
    prints its one error line; --json still prints the result asked for."""
    program = [sys.executable, "-m", "depotbench.eval.cli"]
    ok = subprocess.run([*program, "-q", "scenarios"], capture_output=True, text=True)
    assert (ok.returncode, ok.stdout, ok.stderr) == (0, "", "")
    spec = tmp_path / "s.yaml"
    spec.write_text("name: s\nframes: 5\n")
    ok = subprocess.run([*program, "validate", str(spec), "-q"], capture_output=True, text=True)
    assert (ok.returncode, ok.stdout, ok.stderr) == (0, "", "")
    bad = subprocess.run(
        [*program, "-q", "validate", str(tmp_path / "none.yaml")], capture_output=True, text=True
    )
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.strip().splitlines() == [
        f"depotbench validate: error: {tmp_path / 'none.yaml'}: no such file"
    ]
    asked = subprocess.run([*program, "-q", "scenarios", "--json"], capture_output=True, text=True)
    assert asked.returncode == 0 and json.loads(asked.stdout) and asked.stderr == ""


def test_verbose_and_quiet_are_exclusive(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["-v", "-q", "scenarios"])
    assert exit_.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err


def test_scenarios_json_lists_the_library(capsys):
    from depotbench.scenes import library

    assert main(["scenarios", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [s["name"] for s in listed] == library.names(None)
    assert all(set(s) == {"name", "tags", "description"} for s in listed)


# validate: every kind of file recognised, and each problem on its own line


def test_validate_recognises_every_kind(capsys):
    files = [
        ROOT / "scenes/suites/demo.yaml",
        ROOT / "assets/sweeps/smallest.yaml",
        ROOT / "assets/gates/walking-ci.yaml",
        ROOT / "scenes/library/walking_xyz.yaml",
    ]
    assert main(["validate", *map(str, files), "--json"]) == 0
    found = {Path(c["file"]).name: (c["kind"], c["ok"]) for c in json.loads(capsys.readouterr().out)}
    assert found == {
        "demo.yaml": ("suite", True),
        "smallest.yaml": ("sweep spec", True),
        "walking-ci.yaml": ("gate file", True),
        "walking_xyz.yaml": ("scenario", True),
    }


BAD_FILES = {
    "sweep-unknown-field": ("sweep: s\nsequences: [a]\nbase: 1\n", "base: unknown field"),
    "sweep-missing-sequence": ("sweep: s\nsequences: [nowhere]\n", "nowhere"),
    "sweep-bad-strategy": ("sweep: s\nsequences: [a]\nstrategies: [magic]\n", "magic"),
    "gates-no-checks": (
        "gates: g\nrun:\n  sequences: [a]\nchecks: []\n",
        "checks: List should have at least 1",
    ),
    "gates-unknown-budget": (
        "gates: g\nrun:\n  sequences: [a]\nchecks:\n  - name: c\n    budgets: {speed: {max: 1}}\n",
        "unknown budget 'speed'",
    ),
    "scenario-two-problems": ("name: s\nframes: -3\nfoo: 1\n", "frames: Input should be greater"),
    "suite-bad-knob": ("suite: s\nbase: default\nvary: {frames: [0]}\n", "s.yaml"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_validate_reports_each_problem_in_one_line(case, tmp_path, capsys):
    text, needle = BAD_FILES[case]
    (tmp_path / "a").mkdir()  # a folder that is no sequence, for the sweep's sequences: [a]
    path = tmp_path / "s.yaml"
    path.write_text(text)
    assert main(["validate", str(path)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert captured.out == ""
    assert lines and all(line.startswith(f"depotbench validate: error: {path}") for line in lines)
    assert any(needle in line for line in lines), lines
    if case == "scenario-two-problems":
        assert len(lines) == 2  # each problem on its own line


def test_validate_checks_every_file_given(tmp_path, capsys):
    good = tmp_path / "good.yaml"
    good.write_text("name: g\nframes: 5\n")
    assert main(["validate", str(tmp_path / "missing.yaml"), str(good)]) == 2
    captured = capsys.readouterr()
    assert f"{good}: ok: scenario" in captured.out
    assert "missing.yaml: no such file" in captured.err


# Shell completion, read back by the shells


def test_bash_completion_completes_commands_and_choices(tmp_path):
    script = tmp_path / "depotbench.bash"
    out = subprocess.run(
        [sys.executable, "-m", "depotbench.eval.cli", "completion", "bash"], capture_output=True, text=True
    )
    assert out.returncode == 0
    script.write_text(out.stdout)

    def complete(*words: str) -> set[str]:
        line = "depotbench " + " ".join(words)
        program = (
            f"source {script}\n"
            f"COMP_WORDS=({line}); COMP_CWORD={len(words)}; COMP_LINE='{line}'; COMP_POINT=${{#COMP_LINE}}\n"
            "_shtab_depotbench depotbench\nprintf '%s\\n' \"${COMPREPLY[@]}\"\n"
        )
        result = subprocess.run(["bash", "-c", program], capture_output=True, text=True, check=True)
        return {w.strip() for w in result.stdout.split()}

    assert "run" in complete("ru")
    assert "export-dataset" in complete("exp")
    assert {"box_epipolar_flow", "box_rule"} <= complete("run", "--strategy", "box")
    assert "--version" in complete("--ver")
    assert {"--json", "--quiet"} <= complete("check", "--")


@pytest.mark.skipif(shutil.which("zsh") is None, reason="zsh not installed (make test installs it)")
def test_zsh_completion_loads_in_zsh(tmp_path):
    folder = tmp_path / "functions"
    folder.mkdir()
    out = subprocess.run(
        [sys.executable, "-m", "depotbench.eval.cli", "completion", "zsh"], capture_output=True, text=True
    )
    assert out.returncode == 0 and out.stdout.startswith("#compdef depotbench")
    (folder / "_depotbench").write_text(out.stdout)
    subprocess.run(["zsh", "-n", str(folder / "_depotbench")], check=True)
    program = (
        f"fpath=({folder} $fpath); autoload -U compinit; compinit -u -d {tmp_path}/dump; "
        "print -r -- ${_comps[depotbench]}"
    )
    result = subprocess.run(["zsh", "-f", "-c", program], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "_depotbench"  # compinit found and registered it


FUZZ = {
    "completion-unknown-shell": (["completion", "fish"], "argument shell: invalid choice: 'fish'"),
    "completion-no-shell": (["completion"], "the following arguments are required: shell"),
    "validate-nothing": (["validate"], "the following arguments are required: FILE"),
    "verbose-and-quiet": (["scenarios", "-v", "-q"], "not allowed with argument"),
    "unknown-option-after-command": (["scenarios", "--bogus"], "depotbench scenarios: error: unrecognized"),
}


@pytest.mark.parametrize("case", sorted(FUZZ))
def test_bad_use_of_the_conventions_is_one_line_and_exit_2(case, capsys):
    argv, needle = FUZZ[case]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_.value.code == 2
    assert len(err) == 1 and needle in err[0], err


@pytest.mark.render
def test_a_sweep_that_generates_its_suite_prints_only_json_on_stdout(tmp_path):
    """The suite's and the sweep's status lines go to stderr (they were print()s on stdout,
    which broke --json whenever a sweep had sequences to render)."""
    (tmp_path / "suite.yaml").write_text("suite: tiny\nbase: smoke\noverrides: {frames: 4}\nseeds: [1]\n")
    (tmp_path / "spec.yaml").write_text("sweep: tiny\nsuite: suite.yaml\nstrategies: [none]\n")
    done = subprocess.run(
        [sys.executable, "-m", "depotbench.eval.cli", "sweep", str(tmp_path / "spec.yaml")]
        + ["-o", str(tmp_path / "sw"), "--workers", "1", "--json"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == json.loads((tmp_path / "sw" / "summary.json").read_text())
    assert "1 sequences: 0 complete" in done.stderr and "sweep tiny: 1 runs" in done.stderr
