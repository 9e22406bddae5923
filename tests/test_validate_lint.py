"""``depotbench validate`` as a linter: every problem of a file in one pass, each one line
naming file, line and field; budgets a figure can never meet refused; a YAML typo named
as the YAML field (not a ``--set`` flag nobody typed); the bench's own ``camera.yaml``
read as a camera file; and each shipped sweep's run count equal to the jobs the engine
expands."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from depotbench.core.examples import Kind, examples
from depotbench.eval.cli.main import main
from depotbench.eval.gates.budgets import load_gates
from depotbench.eval.sweep.engine import expand, suite_file
from depotbench.eval.sweep.spec import load_sweep
from depotbench.scenes.schema import SpecError
from depotbench.scenes.suite import load_suite, variations

from tests.sequences import SMALL, write_sequence

ERROR = "depotbench validate: error: "


def lint(capsys, *names: object) -> tuple[int, list[str], list[str]]:
    code = main(["validate", *map(str, names)])
    captured = capsys.readouterr()
    err = [line.removeprefix(ERROR) for line in captured.err.splitlines()]
    return code, captured.out.splitlines(), err


FIVE = """\
gates: five
descripton: a misspelt field
run:
  sequences: [nowhere]
  strategies: [none, prior_flow]
  thresholds:
    prior_flow:
      kk: {grid: [2.0]}
checks:
  - name: c
    budgets:
      rejection_recall: {min: 2}
      speed: {max: 1}
"""


def test_a_file_with_five_problems_gives_five_lines_each_naming_line_and_field(capsys, tmp_path: Path):
    path = tmp_path / "five.yaml"
    path.write_text(FIVE)
    code, out, err = lint(capsys, path)
    assert code == 2 and out == []
    expected = [  # (line, field, what): one line each, in the file's order of checks
        (12, "checks.0.budgets.rejection_recall", "min: 2 is outside the values of rejection_recall"),
        (13, "checks.0.budgets.speed", "unknown budget 'speed'"),
        (2, "descripton", "unknown field"),
        (8, "run.thresholds.prior_flow.kk", "unknown setting (known: "),
        (4, "run.sequences.0", "is not a folder"),
    ]
    assert len(err) == len(expected), err
    for line, (number, field, what) in zip(err, expected, strict=True):
        assert line.startswith(f"{path}:{number}: {field}: "), line
        assert what in line, line


@pytest.mark.parametrize(
    ("budget", "never"),
    [
        ("rejection_recall: {min: 2}", "hold"),
        ("rejection_recall: {min: -0.5}", "fail"),
        ("ate_rmse_m: {max: -0.01}", "hold"),
        ("rho_percent.mean: {min: 101}", "hold"),
        ("lost_fraction.worst: {max: 1.5}", "fail"),
        ("success_rate: {min: 1.2}", "hold"),
    ],
)
def test_a_budget_outside_its_figures_values_is_refused_by_validate_and_check(
    capsys, tmp_path: Path, budget: str, never: str
):
    path = tmp_path / "g.yaml"
    seq = tmp_path / "seq"
    write_sequence(seq, n=2, with_flow=False)
    path.write_text(
        f"gates: g\nrun:\n  sequences: [seq]\nchecks:\n  - name: c\n    budgets:\n      {budget}\n"
    )
    code, _, err = lint(capsys, path)
    assert code == 2 and len(err) == 1, err
    assert f"can never {never}" in err[0] and err[0].startswith(f"{path}:7: checks.0.budgets.")
    with pytest.raises(SpecError, match=f"can never {never}"):  # `depotbench check` loads it so
        load_gates(path)


def test_budgets_at_the_edges_of_their_figures_values_are_valid(capsys, tmp_path: Path):
    write_sequence(tmp_path / "seq", n=2, with_flow=False)
    path = tmp_path / "g.yaml"
    path.write_text(
        "gates: g\nrun:\n  sequences: [seq]\nchecks:\n  - name: c\n    budgets:\n"
        "      rejection_recall: {min: 1, max: 1}\n      ate_rmse_m: {min: 0}\n"
        "      rho_percent: {min: -500, max: 100}\n      ate_rmse_m.vs_baseline: {max: -2}\n"
    )
    code, out, err = lint(capsys, path)
    assert code == 0, err
    assert out == [
        f"{path}: ok: gate file, 'g', 1 check, 4 budgets: 1 sequence x 1 tracker x 1 detector x "
        "1 variant = 1 run"
    ]


def test_a_yaml_typo_names_the_yaml_field_not_a_command_line_flag(capsys, tmp_path: Path):
    write_sequence(tmp_path / "seq", n=2, with_flow=False)
    spec = tmp_path / "s.yaml"
    spec.write_text(
        "sweep: s\nsequences: [seq]\nstrategies: [box_rule]\nthresholds:\n  box_rule:\n    kk: {grid: [1]}\n"
    )
    code, _, err = lint(capsys, spec)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"{spec}:6: thresholds.box_rule.kk: unknown setting (known: ")
    assert "box_dilation_px" in err[0] and "--set" not in err[0]
    # The sweep itself says the same, before it makes its output folder.
    assert main(["sweep", str(spec), "-o", str(tmp_path / "out")]) == 2
    said = capsys.readouterr().err
    assert "thresholds.box_rule.kk: unknown setting" in said and "--set" not in said
    assert not (tmp_path / "out").exists()


def test_a_written_sequence_and_its_camera_yaml_trajectory_and_results_are_recognised(capsys, tmp_path: Path):
    seq = tmp_path / "seq"
    write_sequence(seq, n=3, with_flow=False)  # SequenceWriter: what `depotbench generate` writes
    assert (seq / "camera.yaml").read_text().startswith("%YAML:1.0")  # which PyYAML refuses
    code, out, err = lint(capsys, seq, seq / "camera.yaml", seq / "groundtruth.txt")
    assert code == 0, err
    k = SMALL
    assert out == [
        f"{seq}: ok: sequence folder, 3 frames, {k.width}x{k.height}, exact ground truth",
        f"{seq / 'camera.yaml'}: ok: camera file, ORB-SLAM settings, {k.width}x{k.height}, "
        f"fx {k.fx:g} fy {k.fy:g} cx {k.cx:g} cy {k.cy:g}, depth factor {k.depth_scale:g}",
        f"{seq / 'groundtruth.txt'}: ok: trajectory, TUM trajectory, 3 poses over 0.1 s",
    ]
    camera = (seq / "camera.yaml").read_text().replace("Camera.fx:", "Camera.fz:")
    (tmp_path / "bad.yaml").write_text(camera)
    code, _, err = lint(capsys, tmp_path / "bad.yaml")
    assert code == 2 and len(err) == 1 and "Camera.fx" in err[0] and "not valid YAML" not in err[0], err


def test_a_folder_that_holds_nothing_the_bench_reads_is_one_line(capsys, tmp_path: Path):
    code, _, err = lint(capsys, tmp_path)
    assert code == 2 and err == [
        f"{tmp_path}: a directory that is no sequence folder (rgb.txt), suite folder "
        "or sweep folder (results.sqlite)"
    ]


SHIPPED = sorted(name for name, e in examples().items() if e.kind in (Kind.SWEEP, Kind.GATES))
RUNS = re.compile(r": (\d+) sequences? x (\d+) trackers? x (\d+) detectors? x (\d+) variants? = (\d+) runs?")


@pytest.mark.parametrize("name", SHIPPED)
def test_each_shipped_sweep_prints_the_run_count_the_engine_expands(capsys, tmp_path: Path, name: str):
    code, out, err = lint(capsys, name)
    assert code == 0, err
    found = RUNS.search(out[0])
    assert found, out
    sequences, runs = int(found[1]), int(found[5])
    # Independent: the engine's own expand over that many sequences (tiny stand-ins for the
    # suite's, each of distinct content, as the engine keys jobs by content).
    path = examples()[name].path
    spec = load_gates(path).run if examples()[name].kind is Kind.GATES else load_sweep(path)
    suite = suite_file(spec, path)
    assert sequences == len(variations(load_suite(suite), suite))
    roots = []
    for i in range(sequences):
        write_sequence(tmp_path / f"s{i}", n=2, seed=i, with_flow=False)
        roots.append((tmp_path / f"s{i}", f"f{i}"))
    assert runs == len(expand(spec, path, roots))


def test_a_file_is_parsed_once_however_many_kinds_ask(tmp_path: Path, capsys, monkeypatch):
    """Finding a file's kind and checking it read its YAML six times: 5000 nested brackets
    took 11.6 s to refuse, six parses of 1.9 s. Now each version of a file is parsed once
    (a scenario twice: its own loader reads it again), and an edited file is parsed again."""
    from depotbench.scenes import schema

    calls: list[Path] = []
    real = schema.read_yaml

    def counted(path: Path):
        calls.append(path)
        return real(path)

    monkeypatch.setattr(schema, "read_yaml", counted)
    deep = tmp_path / "deep.yaml"
    deep.write_text("name: " + "[" * 40 + "]" * 40 + "\n")
    code, _, err = lint(capsys, deep)
    assert code != 0 and len(err) == 1 and "nested" in err[0]
    assert calls == [deep.resolve(), deep]  # kinds and lines, then the scenario loader
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text("sweep: s\nsequences: [nowhere]\nstrategies: [none]\n")
    calls.clear()
    lint(capsys, sweep)
    assert calls == [sweep.resolve()]
    sweep.write_text("sweep: s2\nsequences: [nowhere, elsewhere]\nstrategies: [none]\n")
    calls.clear()
    lint(capsys, sweep)
    assert calls == [sweep.resolve()]  # changed: read again, not taken from before
