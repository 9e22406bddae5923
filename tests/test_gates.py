"""Robustness gates: budgets on closed rows, `depotbench check` (exit codes, JUnit) and the pytest plugin."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from xml.etree import ElementTree as ET

import pytest

from eval.cli import main
from eval.gates import GateFile, evaluate, junit_xml, load_gates
from scenes.schema import SpecError


def _row(sequence: str, strategy: str, ate: float, ms: float, **extra) -> dict:
    row = {
        "key": f"{sequence}-{strategy}",
        "family": "walk",
        "sequence": f"/data/{sequence}",
        "tracker": "builtin",
        "detector": "groundtruth",
        "strategy": strategy,
        "settings": "{}",
        "ate_rmse_m": ate,
        "ate_max_m": ate * 2,
        "rpe_translation_rmse_m": 0.001,
        "rpe_rotation_rmse_deg": 0.1,
        "rejection_recall": None,
        "rejection_precision": None,
        "tracked_fraction": 1.0,
        "track_ms_mean": ms,
        "wall_time_s": 1.0,
    }
    return row | extra


def _gates(checks: str) -> GateFile:
    text = "gates: closed\nrun: {sequences: [x]}\nchecks:\n" + textwrap.indent(textwrap.dedent(checks), "  ")
    import yaml

    return GateFile.model_validate(yaml.safe_load(text))


def test_budgets_on_a_closed_case():
    rows = [
        _row("a", "none", 0.10, 20.0),
        _row(
            "a", "box_rule", 0.02, 30.0, rejection_recall=0.9, rejection_precision=0.5, tracked_fraction=0.95
        ),
        _row("b", "none", 0.08, 10.0),
        _row("b", "box_rule", 0.06, 40.0, rejection_recall=0.7, rejection_precision=0.6),
    ]
    gates = _gates(
        """\
        - name: rejection
          strategies: [box_rule]
          budgets:
            rho_percent: {min: 50}
            time_ratio: {max: 2.0}
            lost_fraction: {max: 0.1}
            rejection_recall: {min: 0.8}
        """
    )
    report = evaluate(gates, rows)
    by_row = {r.row.split()[1]: {v.metric: v for v in r.verdicts} for r in report.results}
    # a: rho = (0.10 - 0.02) / 0.10 = 80 %, time 30 / 20 = 1.5, lost 0.05, recall 0.9: all hold.
    assert math.isclose(by_row["a"]["rho_percent"].value, 80.0)
    assert math.isclose(by_row["a"]["time_ratio"].value, 1.5)
    assert math.isclose(by_row["a"]["lost_fraction"].value, 0.05)
    assert all(v.passed for v in by_row["a"].values())
    # b: rho 25 %, time 4x, recall 0.7: three budgets fail, each named with its row.
    assert math.isclose(by_row["b"]["rho_percent"].value, 25.0)
    assert math.isclose(by_row["b"]["time_ratio"].value, 4.0)
    failed = sorted(v.metric for v in by_row["b"].values() if not v.passed)
    assert failed == ["rejection_recall", "rho_percent", "time_ratio"]
    assert not report.passed
    assert len(report.failures) == 3
    assert all(f.startswith("rejection [walk b builtin groundtruth box_rule]") for f in report.failures)
    xml = ET.fromstring(junit_xml(report))
    suite = xml.find("testsuite")
    assert suite.get("tests") == "2" and suite.get("failures") == "1"
    failure = xml.find(".//testcase[@name='walk b builtin groundtruth box_rule']/failure")
    assert "time_ratio" in failure.get("message") and "rho_percent" in failure.get("message")


def test_a_check_that_selects_nothing_fails_and_a_missing_value_fails_its_budget():
    rows = [_row("a", "none", 0.1, 20.0)]
    gates = _gates(
        """\
        - {name: nothing, strategies: [prior_flow], budgets: {ate_rmse_m: {max: 1}}}
        - {name: recall, strategies: [none], budgets: {rejection_recall: {min: 0.5}}}
        """
    )
    report = evaluate(gates, rows)
    assert report.failures[0] == "nothing: no run matches this check"
    assert "rejection_recall (rejection recall) = missing" in report.failures[1]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        (
            "gates: g\nrun: {sequences: [x]}\nchecks: [{name: c, budgets: {ate: {max: 1}}}]\n",
            "unknown budget 'ate'",
        ),
        (
            "gates: g\nrun: {sequences: [x]}\nchecks: [{name: c, budgets: {ate_rmse_m: {}}}]\n",
            "needs min or max",
        ),
        ("gates: g\nrun: {sequences: [x]}\nchecks: []\n", "checks"),
        ("gates: g\nchecks: [{name: c, budgets: {ate_rmse_m: {max: 1}}}]\n", "run"),
        (
            "gates: g\nrun: {sequences: [x]}\nreference: box_rule\n"
            "checks: [{name: c, budgets: {ate_rmse_m: {max: 1}}}]\n",
            "reference",
        ),
    ],
)
def test_bad_gate_files_name_the_field(tmp_path: Path, text: str, needle: str):
    path = tmp_path / "g.yaml"
    path.write_text(text)
    with pytest.raises(SpecError, match=needle):
        load_gates(path)


# -- end to end on a generated sequence ------------------------------------------------

PASSING = """\
gates: walking
run:
  sequences: [{walking}]
  strategies: [none, box_rule]
checks:
  - name: box-rule-holds
    strategies: [box_rule]
    budgets:
      ate_rmse_m: {{max: 0.5}}
      lost_fraction: {{max: 0.5}}
      rejection_recall: {{min: 0.5}}
      time_ratio: {{max: 20}}
"""
IMPOSSIBLE = (
    PASSING
    + """\
  - name: impossible
    families: ["walking*"]
    budgets:
      ate_rmse_m: {{max: 1.0e-9}}
"""
)


@pytest.fixture(scope="module")
def walking(tmp_path_factory) -> Path:
    from scenes import library
    from scenes.schema import to_scenario
    from sim.generate import generate

    scenario = library.get("walking_static").model_copy(update={"frames": 24, "duration_s": None})
    return generate(to_scenario(scenario), tmp_path_factory.mktemp("walk") / "walking", progress=False)


@pytest.mark.render
def test_check_passes_a_good_gate_file_and_fails_an_impossible_budget_naming_it(
    walking: Path, tmp_path: Path, capsys
):
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text(PASSING.format(walking=walking))
    bad.write_text(IMPOSSIBLE.format(walking=walking))
    out = tmp_path / "matrix"
    assert (
        main(["check", str(good), "-o", str(out), "--junit", str(tmp_path / "good.xml"), "--workers", "1"])
        == 0
    )
    shown = capsys.readouterr().out
    assert "all budgets held" in shown and "FAILED" not in shown
    suite = ET.parse(tmp_path / "good.xml").getroot().find("testsuite")
    assert suite.get("failures") == "0" and int(suite.get("tests")) == 1

    # The same matrix (rows reused from the folder), one budget no run can meet.
    code = main(["check", str(bad), "-o", str(out), "--junit", str(tmp_path / "bad.xml"), "--workers", "1"])
    assert code == 1
    shown = capsys.readouterr().out
    failed = [line for line in shown.splitlines() if line.startswith("FAILED")]
    assert len(failed) == 2  # none and box_rule runs of the walking family
    assert all(
        line.startswith("FAILED impossible [walking_static walking builtin groundtruth") for line in failed
    )
    assert all("ate_rmse_m (ATE RMSE (m))" in line and "budget <= 1e-09" in line for line in failed)
    root = ET.parse(tmp_path / "bad.xml").getroot()
    failures = root.findall(".//testcase[@classname='depotbench.walking.impossible']/failure")
    assert len(failures) == 2 and all("ate_rmse_m" in f.get("message") for f in failures)
    assert not root.findall(".//testcase[@classname='depotbench.walking.box-rule-holds']/failure")


def test_check_refuses_a_bad_gate_file_with_exit_2(tmp_path: Path, capsys):
    path = tmp_path / "g.yaml"
    path.write_text(
        "gates: g\nrun: {sequences: [nowhere]}\nchecks: [{name: c, budgets: {ate_rmse_m: {max: 1}}}]\n"
    )
    assert main(["check", str(path), "-o", str(tmp_path / "out")]) == 2
    assert "nowhere" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.render
def test_the_pytest_plugin_runs_gates_and_budgets_as_fixtures(walking: Path, tmp_path: Path, pytester):
    (pytester.path / "good.yaml").write_text(PASSING.format(walking=walking))
    (pytester.path / "bad.yaml").write_text(IMPOSSIBLE.format(walking=walking))
    pytester.makepyfile(
        """
        import pytest

        @pytest.mark.depotbench_gates("good.yaml")
        def test_good(depotbench_gates):
            assert depotbench_gates.report.passed

        @pytest.mark.depotbench_gates("bad.yaml")
        def test_bad(depotbench_gates):
            pass

        def test_run(depotbench_run):
            row = depotbench_run("walking_static", strategy="box_rule", frames=24,
                                 budgets={"ate_rmse_m": {"max": 0.5}})
            assert row["strategy"] == "box_rule" and row["rho_percent"] is not None

        @pytest.mark.depotbench_budgets(rejection_recall={"min": 1.01})
        def test_marked(depotbench_run):
            depotbench_run("walking_static", strategy="box_rule", frames=24)
        """
    )
    result = pytester.runpytest_subprocess(
        f"--depotbench-dir={tmp_path / 'plugin'}", "--depotbench-workers=1", "-p", "no:cacheprovider"
    )
    result.assert_outcomes(passed=2, failed=2)
    result.stdout.fnmatch_lines(["*impossible [[]walking_static walking builtin groundtruth*ate_rmse_m*"])
    result.stdout.fnmatch_lines(["*rejection_recall (rejection recall) = *budget >= 1.01*"])
