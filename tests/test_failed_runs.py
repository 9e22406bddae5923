"""A failed program leaves what is needed to debug it, and failed rows can be run again
(O10 of reliability-probe-2.md, issue 50 item 7).

``run`` keeps its folder at ``-o`` (failure.json, program.log, the scratch folder with the
rendered settings and what the program wrote); a sweep keeps ``failures/<key>/`` for its
last ``KEEP_FAILURES`` failures. A failed row is reused on resume, said so in the status
line, and ``--retry-failed`` runs it again.
"""

from __future__ import annotations

import json
import os
import pickle
import shlex
import sys
from pathlib import Path

import pytest
from depotbench.core.output import read_marker
from depotbench.eval.sweep.store import ResultStore
from depotbench.eval.trackers import evidence
from depotbench.eval.trackers.base import TrackerError
from depotbench.eval.trackers.evidence import Evidence

from tests.sequences import write_sequence
from tests.test_output import cli, one_error_line

FAILING = """
import os, sys
from pathlib import Path
scratch = Path.cwd()
print("starting on", sys.argv[1])
for i in range(30):
    print(f"step {i} of the program's own log", file=sys.stderr)
Path(sys.argv[2]).write_text("# depotbench keypoints 1\\n")
(scratch / "debug.bin").write_bytes(b"x" * int(os.environ.get("BIG", "0")))
if os.environ.get("FIFO"):
    os.mkfifo(scratch / "a-pipe")
if Path(os.environ.get("FAIL_FLAG", "/nonexistent")).exists() or not os.environ.get("FAIL_FLAG"):
    print("giving up: no features", file=sys.stderr)
    sys.exit(3)
truth = Path(sys.argv[1]) / "groundtruth.txt"
Path(sys.argv[3]).write_text(truth.read_text())
"""

TEMPLATE = "Camera.fx: {{ camera.fx }}\nwindow: {{ params.window }}\n"


@pytest.fixture
def seq(tmp_path: Path) -> Path:
    write_sequence(tmp_path / "seq", n=4, with_flow=False)
    return tmp_path / "seq"


def _command(tmp_path: Path) -> str:
    script = tmp_path / "failing.py"
    script.write_text(FAILING)
    return f"{shlex.quote(sys.executable)} {script} {{sequence}} {{keypoints}} {{trajectory}} {{settings}}"


def test_a_failed_run_keeps_its_folder_with_log_settings_command_and_outputs(
    seq: Path, tmp_path: Path, capsys
):
    template = tmp_path / "settings.j2"
    template.write_text(TEMPLATE)
    out = tmp_path / "run"
    code, _, err = cli(
        capsys, "run", seq, "-o", out, "--slam", "cmd", "--command", _command(tmp_path),
        "--settings-template", template, "--param", "window=7",
    )  # fmt: skip
    assert code == 2
    one_error_line(err, "exited with code 3 (giving up: no features)", str(out))
    assert read_marker(out) is not None
    facts = json.loads((out / "failure.json").read_text())
    assert "exited with code 3" in facts["reason"]
    assert facts["argv"][0] == sys.executable and facts["argv"][1].endswith("failing.py")
    assert shlex.split(facts["command"]) == facts["argv"]
    environment = facts["environment"]
    assert environment["DEPOTBENCH_PARAM_WINDOW"] == "7"
    assert Path(environment["DEPOTBENCH_SEQUENCE"]).name == seq.name
    assert facts["argv"][-1] == environment["DEPOTBENCH_SETTINGS"]
    # The rendered settings, as the program read them; what it wrote; its whole log.
    assert (out / "scratch" / "settings.yaml").read_text() == "Camera.fx: 50.0\nwindow: 7\n"
    assert json.loads((out / "scratch" / "parameters.json").read_text()) == {"window": 7}
    assert (out / "scratch" / "keypoints.txt").read_text() == "# depotbench keypoints 1\n"
    log = (out / "program.log").read_text()
    assert all(f"step {i} of the program's own log" in log for i in range(30))
    assert "starting on" in log
    record = json.loads((out / "record.json").read_text())
    assert "exited with code 3" in record["failure"]
    assert {entry["file"] for entry in facts["skipped"]} == {"view/"}  # the sequence: links


def test_what_a_failed_run_keeps_is_bounded_and_no_pipe_blocks_it(
    seq: Path, tmp_path: Path, capsys, monkeypatch
):
    monkeypatch.setattr(evidence, "KEEP_MAX_BYTES", 20_000)
    monkeypatch.setenv("BIG", "50000")
    monkeypatch.setenv("FIFO", "1")
    out = tmp_path / "run"
    code, _, err = cli(capsys, "run", seq, "-o", out, "--slam", "cmd", "--command", _command(tmp_path))
    assert code == 2, err
    facts = json.loads((out / "failure.json").read_text())
    why = {entry["file"]: entry["why"] for entry in facts["skipped"]}
    assert "past the bound" in why["debug.bin"] and why["a-pipe"] == "not a regular file"
    assert "settings.yaml" in facts["kept"] and "keypoints.txt" in facts["kept"]
    assert sum(p.stat().st_size for p in (out / "scratch").rglob("*") if p.is_file()) <= 20_000


def test_a_tracker_error_crosses_processes_with_its_evidence():
    kept = Evidence(("prog", "a b"), (("DEPOTBENCH_SEQUENCE", "/s"),), (("settings.yaml", b"x: 1\n"),))
    again = pickle.loads(pickle.dumps(TrackerError("prog: exited with code 3", "the log", kept)))
    assert (str(again), again.log, again.evidence) == ("prog: exited with code 3", "the log", kept)


def _sweep_spec(tmp_path: Path, seq: Path) -> Path:
    spec = tmp_path / "spec.yaml"
    tracker = {"name": "flaky", "command": _command(tmp_path), "env": {"FAIL_FLAG": str(tmp_path / "fail")}}
    spec.write_text(
        f"sweep: flaky\nsequences: [{seq}]\nstrategies: [none]\ntrackers: [{json.dumps(tracker)}]\n"
    )
    return spec


def _failures(out: Path) -> list[str]:
    with ResultStore(out / "results.sqlite", readonly=True) as store:
        return [record.failure or "" for record in store.records()]


def test_a_failed_sweep_row_keeps_its_folder_is_reused_and_retried_on_request(
    seq: Path, tmp_path: Path, capsys, caplog
):
    spec, out = _sweep_spec(tmp_path, seq), tmp_path / "sw"
    (tmp_path / "fail").touch()
    code, _, err = cli(capsys, "sweep", spec, "-o", out, "--workers", "1")
    assert code == 0, err
    [failure] = _failures(out)
    assert "exited with code 3" in failure
    [kept] = (out / "failures").iterdir()
    assert json.loads((kept / "failure.json").read_text())["reason"] == failure
    facts = json.loads((kept / "failure.json").read_text())
    assert facts["environment"]["FAIL_FLAG"] == str(tmp_path / "fail")
    assert "giving up: no features" in (kept / "program.log").read_text()
    assert f"{out / 'failures'}/KEY/" in caplog.text
    caplog.clear()

    os.remove(tmp_path / "fail")  # the program would pass now
    code, _, err = cli(capsys, "sweep", spec, "-o", out, "--workers", "1")
    assert code == 0, err
    assert "1 of them failed and are reused: --retry-failed runs them again" in caplog.text
    assert "exited with code 3" in _failures(out)[0]
    caplog.clear()

    code, _, err = cli(capsys, "sweep", spec, "-o", out, "--workers", "1", "--retry-failed")
    assert code == 0, err
    assert "its 1 failed runs run again" in caplog.text
    assert _failures(out) == [""]
    with ResultStore(out / "results.sqlite", readonly=True) as store:
        assert store.records()[0].ate_rmse_m < 1e-6


def test_a_sweep_keeps_only_its_newest_failures(seq: Path, tmp_path: Path):
    from depotbench.eval.metrics.record import RunIdentity, RunRecord
    from depotbench.eval.sweep.engine import Failure, keep_failure

    folder = tmp_path / "failures"
    (folder / ".k5.partial-1234").mkdir(parents=True)  # what a killed sweep left: cleaned
    for i in range(5):
        run = RunIdentity(f"k{i}", "f", "s", "p", "t", "gt", "none")
        record = RunRecord.failed(run, f"failure {i}", 4, 0.1, "v")
        kept = keep_failure(folder, Failure(record, "log", None), keep=3)
        os.utime(kept / ".depotbench.json", ns=(i * 10**9, i * 10**9))  # a clock tick apart
    assert sorted(p.name for p in folder.iterdir()) == ["k2", "k3", "k4"]
    (folder / "k9").mkdir()  # not ours: never replaced
    record = RunRecord.failed(RunIdentity("k9", "f", "s", "p", "t", "gt", "none"), "x", 4, 0.1, "v")
    with pytest.raises(Exception, match="not a failed run's folder"):
        keep_failure(folder, Failure(record, "log", None), keep=3)
    assert sorted(p.name for p in folder.iterdir()) == ["k2", "k3", "k4", "k9"]


@pytest.mark.slow  # three checks, ~7 s: the sweep test above covers the engine by default
def test_check_runs_its_failed_rows_again_on_request(seq: Path, tmp_path: Path, capsys):
    tracker = {"name": "flaky", "command": _command(tmp_path), "env": {"FAIL_FLAG": str(tmp_path / "fail")}}
    gate = tmp_path / "gates.yaml"
    gate.write_text(
        f"gates: flaky\nrun:\n  sequences: [{seq}]\n  strategies: [none]\n"
        f"  trackers: [{json.dumps(tracker)}]\n"
        "checks:\n  - name: accurate\n    trackers: [flaky]\n    budgets: {ate_rmse_m: {max: 0.01}}\n"
    )
    out = tmp_path / "chk"
    (tmp_path / "fail").touch()
    assert cli(capsys, "check", gate, "-o", out, "--workers", "1")[0] == 1  # the run failed
    assert (out / "failures").is_dir()
    os.remove(tmp_path / "fail")
    assert cli(capsys, "check", gate, "-o", out, "--workers", "1")[0] == 1  # reused
    code, stdout, err = cli(capsys, "check", gate, "-o", out, "--workers", "1", "--retry-failed")
    assert code == 0, stdout + err
    assert _failures(out) == [""]
