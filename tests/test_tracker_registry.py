"""A new tracker is one module and one entry of the registry: the command line, sweep
specs and the run take it from the table (tests/programs/truth_tracker.py is the module)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.trackers.registry import TRACKERS, TrackerType

ENTRY = TrackerType(
    "truth",
    "tests.programs.truth_tracker",
    "the true poses, offset on every other frame (tests only)",
    per_keypoint=False,
    external=False,
    parameters=True,
)


@pytest.fixture
def truth(monkeypatch):
    monkeypatch.setitem(TRACKERS, "truth", ENTRY)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("registry") / "s"
    assert main(["generate", "smoke", "-o", str(out), "--frames", "6", "--seed", "4"]) == 0
    return out


def test_the_command_line_runs_a_tracker_the_registry_names(truth, sequence: Path, tmp_path: Path, capsys):
    assert main(["run", str(sequence), "-o", str(tmp_path / "exact"), "--slam", "truth"]) == 0
    exact = json.loads((tmp_path / "exact" / "metrics.json").read_text())
    assert exact["tracker"] == "truth" and exact["ate_m"]["rmse"] < 1e-9
    args = ["run", str(sequence), "-o", str(tmp_path / "off"), "--slam", "truth", "--param", "offset_m=0.02"]
    assert main(args) == 0
    off = json.loads((tmp_path / "off" / "metrics.json").read_text())
    assert 0.005 < off["ate_m"]["rmse"] < 0.02  # half the frames 2 cm off, after alignment
    # what the table says it takes: no rejection strategy of the built-in tracker
    assert (
        main(["run", str(sequence), "-o", str(tmp_path / "x"), "--slam", "truth", "--strategy", "box_rule"])
        == 2
    )
    assert "needs the built-in tracker" in capsys.readouterr().err


def test_a_tracker_missing_from_the_table_is_refused_naming_the_choices(
    sequence: Path, tmp_path: Path, capsys
):
    with pytest.raises(SystemExit) as exited:
        main(["run", str(sequence), "-o", str(tmp_path / "x"), "--slam", "truth"])
    assert exited.value.code == 2 and "choose from 'builtin', 'orbslam3', 'cmd'" in capsys.readouterr().err


def test_a_sweep_runs_a_tracker_the_registry_names(truth, sequence: Path, tmp_path: Path):
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"sweep: t\nsequences: [{sequence}]\nstrategies: [none]\ntrackers: [builtin, truth]\n")
    # one worker runs in this process, where the test's entry is in the table
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw"), "--workers", "1"]) == 0
    summary = json.loads((tmp_path / "sw" / "summary.json").read_text())
    trackers = {c["tracker"]: c for c in summary["configurations"]}
    assert set(trackers) == {"builtin", "truth"}
    assert trackers["truth"]["ate_rmse_m"] < 1e-9 < trackers["builtin"]["ate_rmse_m"]
