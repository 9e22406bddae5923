"""The Python API (``import depotbench``): the documented example runs as written, and each
function gives what the command line gives for the same job, read back from the files the
command line writes (record.json, results.csv, its exit status) or from evo."""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.cli.main import main
from depotbench.eval.metrics.alignment import Alignment
from depotbench.eval.metrics.evaluate import ComparisonOptions
from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS, RunRecord
from depotbench.eval.metrics.trajectory import read_tum

import depotbench
from tests.evo_reference import evo_ape

ROOT = Path(__file__).resolve().parents[1]
API_PAGE = ROOT / "docs" / "api.md"
EXAMPLES = ROOT / "assets" / "examples"


def example_code() -> str:
    blocks = re.findall(r"```python\n(.*?)```", API_PAGE.read_text(encoding="utf-8"), flags=re.S)
    assert len(blocks) == 1, "docs/api.md holds one example"
    return blocks[0]


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, str]:
    """The page's example run as a user runs it: a fresh interpreter in an empty folder."""
    where = tmp_path_factory.mktemp("api")
    done = subprocess.run(
        [sys.executable, "-c", example_code()],
        cwd=where,
        capture_output=True,
        text=True,
        env=os.environ | {"MUJOCO_GL": "egl"},
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return where / "work", done.stdout


def test_the_documented_example_runs_and_says_what_it_did(session):
    work, out = session
    assert "30 frames of walking_static" in out
    assert "gates passed" in out
    assert (work / "report" / "index.html").is_file()
    assert (work / "run-box_rule" / "record.json").is_file()
    # Each swept run printed once: 2 seeds x (none + prior_flow at 2 values).
    assert len(re.findall(r"^[12] (none|prior_flow) ", out, flags=re.M)) == 6


def test_a_run_is_the_record_the_command_line_writes(session, tmp_path: Path):
    work, _ = session
    sequence = work / "walking-7"
    record = depotbench.run(sequence, strategy="box_rule", settings={"box_dilation_px": 8})
    assert isinstance(record, RunRecord)
    cli_run = tmp_path / "cli-run"
    args = ["run", str(sequence), "-o", str(cli_run), "--strategy", "box_rule"]
    assert main([*args, "--set", "box_dilation_px=8"]) == 0
    written = json.loads((cli_run / "record.json").read_text())
    for name in DETERMINISTIC_FIELDS:
        assert getattr(record, name) == written[name], name
    # The example's own run folder (out=) holds the same record.
    stored = RunRecord.from_row(json.loads((work / "run-box_rule" / "record.json").read_text()))
    assert {n: getattr(stored, n) for n in DETERMINISTIC_FIELDS} == {
        n: getattr(record, n) for n in DETERMINISTIC_FIELDS
    }


def test_a_sweep_returns_the_rows_it_stored(session):
    work, _ = session
    result = depotbench.sweep(work / "sweep.yaml", work / "sweep", workers=1)
    assert result.written == 0  # resumed: every run is in the folder already
    with open(work / "sweep" / "results.csv", newline="") as f:
        stored = {row["key"]: row for row in csv.DictReader(f)}
    assert {r.key for r in result.records} == set(stored)
    for record in result.records:
        row = stored[record.key]
        assert float(row["ate_rmse_m"]) == pytest.approx(record.ate_rmse_m, rel=1e-12)
        assert row["strategy"] == record.strategy and row["settings"] == record.settings
    summary = json.loads((work / "sweep" / "summary.json").read_text())
    assert result.best == summary["best"]
    # The scored runs carry rho against the none run of their sequence, as results.csv does.
    assert [run.record for run in result.runs] == result.records
    for run in result.runs:
        shown = stored[run.key]["rho_percent"]
        if shown == "":
            assert run.rho_percent is None
        else:
            assert float(shown) == pytest.approx(run.rho_percent, rel=1e-9)
    assert all(run.rho_percent is not None for run in result.runs)  # every sequence has its none run


def test_check_agrees_with_the_command_lines_exit(session, tmp_path: Path):
    work, _ = session
    strict = (work / "gates.yaml").read_text().replace("lost_fraction: {max: 0.5}", "ate_rmse_m: {max: 1e-9}")
    gates = work / "strict-gates.yaml"
    gates.write_text(strict)
    verdict = depotbench.check(gates, work / "sweep")
    assert not verdict.passed
    assert len(verdict.failures) == 4 and all("ate_rmse_m" in line for line in verdict.failures)
    assert main(["check", str(gates), "-o", str(work / "sweep")]) == 1
    assert depotbench.check(work / "gates.yaml", work / "sweep").passed
    assert main(["check", str(work / "gates.yaml"), "-o", str(work / "sweep")]) == 0


def test_compare_pairs_a_folder_with_itself_as_no_change(session):
    work, _ = session
    found = depotbench.compare(work / "sweep", work / "sweep")
    (comparison,) = found.values()
    assert comparison.comparisons and not comparison.regressions(0.0)
    assert all(c.change.change in (0.0, None) for c in comparison.comparisons if c.figure == "ate_rmse_m")


def test_evaluate_is_evo():
    gt, est = EXAMPLES / "fr1_xyz_groundtruth.txt", EXAMPLES / "fr1_xyz_rgbdslam.txt"
    result = depotbench.evaluate(gt, est, ComparisonOptions(alignment=Alignment.SIM3))
    expected = evo_ape(read_tum(gt), read_tum(est), "sim3")
    assert result.pairs == 786
    assert result.ate.statistics.rmse == pytest.approx(expected["rmse"], rel=1e-6)


def test_changes_are_checked_as_the_schema_checks_them():
    spec = depotbench.scenario("walking_static", seed=3, frames=12, flow=True)
    assert (spec.seed, spec.frames, spec.flow) == (3, 12, True)  # flow: a field with no limits
    assert depotbench.scenario("default", frames=5).frames == 5


def test_bad_input_is_one_line_naming_the_field(tmp_path: Path):
    with pytest.raises(InputError, match=r"^seed -1: .*the scenario's seed\)$"):
        depotbench.scenario("walking_static", seed=-1)
    with pytest.raises(InputError, match="no library scenario named 'nowhere'"):
        depotbench.scenario("nowhere")
    with pytest.raises(InputError, match="colour: not a field of a scenario"):
        depotbench.scenario("walking_static", colour="red")
    with pytest.raises(InputError, match="unknown strategy 'fast'"):
        depotbench.run(tmp_path, strategy="fast")
    with pytest.raises(InputError, match="settings: unknown setting 'kk'"):
        depotbench.run(tmp_path, settings={"kk": 1})
    with pytest.raises(InputError, match="settings: setting n_features=800.5 must be a whole number"):
        depotbench.run(tmp_path, settings={"n_features": 800.5})
    with pytest.raises(InputError, match="detector"):
        depotbench.run(tmp_path, detector="yolo9000")
    with pytest.raises(InputError, match="compare needs two folders"):
        depotbench.compare(tmp_path)


def test_a_users_folder_is_never_generated_over(tmp_path: Path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(InputError):
        depotbench.generate("walking_static", mine, frames=2, overwrite=True)
    assert (mine / "notes.txt").read_text() == "keep"


def test_import_depotbench_loads_no_heavy_part():
    heavy = "('mujoco', 'cv2', 'onnxruntime', 'scipy')"
    code = f"import sys, depotbench; print(sorted(m for m in {heavy} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
    assert set(depotbench.__all__) >= {"generate", "run", "sweep", "check", "compare", "report", "evaluate"}


def test_json_on_the_command_line_is_what_the_files_and_the_api_hold(session, tmp_path: Path, capsys):
    """--json prints the result in the shape of the file the command writes: run's metrics.json,
    sweep's summary.json, check's verdicts (as the API's GateReport, and the exit status)."""
    work, _ = session
    out = tmp_path / "run"
    capsys.readouterr()
    assert main(["run", str(work / "walking-7"), "-o", str(out), "--strategy", "box_rule", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((out / "metrics.json").read_text())

    assert main(["sweep", str(work / "sweep.yaml"), "-o", str(work / "sweep"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads((work / "sweep" / "summary.json").read_text())

    strict = (work / "gates.yaml").read_text().replace("lost_fraction: {max: 0.5}", "ate_rmse_m: {max: 1e-9}")
    gates = work / "strict-gates-json.yaml"  # beside gates.yaml: its sequences are relative
    gates.write_text(strict)
    for path, code in ((work / "gates.yaml", 0), (gates, 1)):
        assert main(["check", str(path), "-o", str(work / "sweep"), "--json"]) == code
        verdict = json.loads(capsys.readouterr().out)
        expected = depotbench.check(path, work / "sweep")
        assert verdict["passed"] is expected.passed is (code == 0)
        assert verdict["failures"] == expected.failures
        assert len(verdict["results"]) == len(expected.results)
        for shown, result in zip(verdict["results"], expected.results, strict=True):
            assert [b["value"] for b in shown["budgets"]] == [v.value for v in result.verdicts]
