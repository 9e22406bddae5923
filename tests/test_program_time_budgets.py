"""Time budgets for an external program (docs/external-trackers.md, docs/gates.md): its wall
and CPU time per frame as the bench measures them around it, and the per-frame times it may
write to ``{times}``, each bounded by a gate file; the times file read as strictly as the
protocol's other files.

The program is ``tests/programs/timed_slam.py``, whose time per frame is set by its
parameters: ``sleep_ms`` of wall time with no CPU, ``spin_ms`` of CPU time, and
``report_ms`` written to ``{times}``; on a 5-frame 64x48 sequence (no rendering)."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.gates.budgets import derived_rows
from depotbench.eval.sweep.store import ResultStore
from depotbench.eval.trackers.protocol import TIMES_HEADER, ProtocolError, read_times, write_times
from depotbench.sim.sequence import Sequence

from tests.conftest import REPO
from tests.records import record
from tests.sequences import write_sequence

PROGRAM = REPO / "tests" / "programs" / "timed_slam.py"
COMMAND = f"{shlex.quote(sys.executable)} {PROGRAM} {{sequence}} {{parameters}} {{trajectory}} {{times}}"
FRAMES = 5


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Sequence:
    root = tmp_path_factory.mktemp("timed") / "seq"
    write_sequence(root, n=FRAMES)
    return Sequence.open(root)


def _tracker(name: str, parameters: str, indent: str = "    ") -> str:
    return (
        f"{indent}- name: {name}\n{indent}  command: {json.dumps(COMMAND)}\n"
        f"{indent}  parameters: {parameters}\n"
    )


def _check(name: str, tracker: str, budgets: str) -> str:
    return f"  - name: {name}\n    trackers: [{tracker}]\n    budgets: {budgets}\n"


def test_a_programs_measured_and_reported_times_are_bounded_by_a_gate_file(
    sequence: Sequence, tmp_path: Path, capsys
):
    gate = tmp_path / "timed.yaml"
    gate.write_text(
        f"gates: timed\nrun:\n  sequences: [{sequence.root}]\n  strategies: [none]\n  trackers:\n"
        + _tracker("sleeper", "{sleep_ms: 40, spin_ms: 0, report_ms: 0}")
        + _tracker("spinner", "{sleep_ms: 0, spin_ms: 40, report_ms: 0}")
        + _tracker("reporter", "{sleep_ms: 0, spin_ms: 0, report_ms: 7.5}")
        + "checks:\n"
        # Sleeping is wall time: at least the 40 ms slept a frame, and little CPU (the
        # interpreter's start, ~20-40 ms in all, over 5 frames).
        + _check("sleeper-wall", "sleeper", "{wall_ms_per_frame: {min: 40}, cpu_ms_per_frame: {max: 25}}")
        + _check("spinner-cpu", "spinner", "{cpu_ms_per_frame: {min: 40}, wall_ms_per_frame: {min: 40}}")
        # A program that writes {times}: its own figure is the run's tracking time.
        + _check(
            "reporter-own", "reporter", "{track_ms_mean: {min: 7.5, max: 7.5}, track_ms_median: {max: 7.5}}"
        )
        # Against its own none run (the reference): 1, where it read "missing" for a program.
        + _check("sleeper-ratio", "sleeper", "{time_ratio: {min: 1, max: 1}}")
        + _check("reporter-ratio", "reporter", "{time_ratio: {min: 1, max: 1}}")
        + _check("sleeper-fast", "sleeper", "{wall_ms_per_frame: {max: 20}}")
    )
    assert main(["check", str(gate), "-o", str(tmp_path / "out"), "--json", "--workers", "1"]) == 1
    report = json.loads(capsys.readouterr().out)
    by_check: dict[str, list[dict]] = {}
    for result in report["results"]:
        by_check.setdefault(result["check"], []).extend(result["budgets"])
    passed = {name: all(b["passed"] for b in budgets) for name, budgets in by_check.items()}
    assert passed == {
        "sleeper-wall": True,
        "spinner-cpu": True,
        "reporter-own": True,
        "sleeper-ratio": True,
        "reporter-ratio": True,
        "sleeper-fast": False,
    }, by_check
    (fast,) = by_check["sleeper-fast"]
    assert fast["value"] >= 40, fast
    assert report["failures"] == [
        f"sleeper-fast [{report['results'][-1]['run']}]: wall_ms_per_frame (wall time per frame, start-up "
        f"included (ms)) = {fast['value']:.4g}, budget <= 20"
    ]
    # The rows hold what the budgets read: wall time over frames, the program's CPU time.
    rows = {r.tracker: r for r in ResultStore(tmp_path / "out" / "results.sqlite", readonly=True).records()}
    assert rows["sleeper"].wall_ms_per_frame == pytest.approx(1000 * rows["sleeper"].wall_time_s / FRAMES)
    assert rows["sleeper"].track_ms_mean is None and rows["reporter"].track_ms_mean == 7.5
    assert 40 <= rows["spinner"].cpu_ms_per_frame <= rows["spinner"].wall_ms_per_frame * 1.05
    notes = {r["check"]: r["budgets"][0]["note"] for r in report["results"]}
    assert notes["sleeper-ratio"] == "against none, wall time per frame"  # no {times}: wall time
    assert notes["reporter-ratio"] == "against none"  # its own times


def test_a_times_file_gives_each_frame_its_time(sequence: Sequence, tmp_path: Path):
    stamps = list(sequence.timestamps_s)
    path = write_times(tmp_path / "t.txt", stamps[:3] + stamps[4:], [1.5, 0.0, 2.25, 9.0])
    assert path.read_text().startswith(TIMES_HEADER)
    got = read_times(path, sequence)
    assert got[[0, 1, 2, 4]].tolist() == [1.5, 0.0, 2.25, 9.0] and np.isnan(got[3])  # no line: no time


@pytest.mark.parametrize(
    ("body", "line", "problem"),
    [
        ("", None, "is empty: a times file begins with '# depotbench times 1'"),
        ("# depotbench times 2\n", 1, "times file version 2 is unknown"),
        ("# times\n", 1, "the first line must be '# depotbench times 1'"),
        (TIMES_HEADER + "{t0} 1.0 2\n", 3, "expected 2 fields (timestamp ms), found 3"),
        (TIMES_HEADER + "{t0} nan\n", 3, "time nan ms is not a finite number in [0, 3600000]"),
        (TIMES_HEADER + "{t0} -1\n", 3, "time -1 ms is not a finite number"),
        (TIMES_HEADER + "{t0} 4e9\n", 3, "time 4e9 ms is not a finite number"),
        (TIMES_HEADER + "{t0} 1.0\n{t1} 1\n{t0} 2.0\n", 5, "is frame 0's again, whose time is on line 3"),
        (TIMES_HEADER + "99999.5 1.0\n", 3, "timestamp 99999.5 is no frame's"),
    ],
)
def test_a_bad_times_file_is_one_line_naming_the_file_and_line(
    sequence: Sequence, tmp_path: Path, body: str, line: int | None, problem: str
):
    t0, t1 = (f"{t:.6f}" for t in sequence.timestamps_s[:2])
    path = tmp_path / "times.txt"
    path.write_text(body.format(t0=t0, t1=t1))
    with pytest.raises(ProtocolError) as caught:
        read_times(path, sequence)
    message = str(caught.value)
    assert "\n" not in message and problem in message, message
    assert message.startswith(f"{path}:{line}:" if line else f"{path}:"), message


def test_a_directory_at_times_fails_the_run_naming_it(sequence: Sequence, tmp_path: Path):
    (tmp_path / "times.txt").mkdir()
    with pytest.raises(ProtocolError, match="times.txt"):
        read_times(tmp_path / "times.txt", sequence)


def test_the_time_ratio_compares_like_with_like():
    """The tracker's own time where the run has it, else wall time per frame, of both runs:
    never a program's wall time over its reference's own time."""
    none = dict(strategy="none", wall_ms_per_frame=50.0)
    mask = dict(strategy="mask", wall_ms_per_frame=80.0)
    rows = [
        record(key="p0", tracker="prog", **none),
        record(key="p1", tracker="prog", **mask),
        record(key="t0", tracker="timed", track_ms_mean=4.0, **none),
        record(key="t1", tracker="timed", track_ms_mean=6.0, **mask),
        record(key="m0", tracker="mixed", track_ms_mean=4.0, **none),
        record(key="m1", tracker="mixed", **mask),  # its own time missing: wall time of both
        record(key="x0", tracker="reverse", **none),
        record(key="x1", tracker="reverse", track_ms_mean=6.0, **mask),  # the reference has none
    ]
    ratios = {r.key: r.time_ratio for r in derived_rows(rows, "none")}
    assert ratios == {
        "p0": 1.0,
        "p1": 1.6,
        "t0": 1.0,
        "t1": 1.5,
        "m0": 1.0,
        "m1": 1.6,
        "x0": 1.0,
        "x1": None,
    }
