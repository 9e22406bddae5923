"""The user's own program as a full member of sweeps and gates (docs/external-trackers.md):
its parameters swept, the bench's (faulted) boxes handed in, its keypoint decisions scored
against the exact ground truth, and its failures kept as rows.

The program is ``tests/programs/oracle_slam.py``: the true trajectory perturbed by a seeded
``noise_m``, a grid of keypoints rejected inside dynamic boxes grown by ``margin_px``, and
misbehaviours on request (``mode``).
"""

from __future__ import annotations

import csv
import json
import os
import shlex
import shutil
import sys
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.sweep.summary import settings_text
from depotbench.eval.trackers.builtin import true_moving_labels
from depotbench.sim.sequence import Sequence

from tests.conftest import REPO
from tests.test_output import processes_with, wait_until_gone

ORACLE = REPO / "tests" / "programs" / "oracle_slam.py"
COMMAND = (
    f"{shlex.quote(sys.executable)} {ORACLE} {{sequence}} {{detections}} {{parameters}} {{trajectory}} "
    "{keypoints}"
)


@pytest.fixture(scope="module")
def sequences(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("external")
    for name, seed in (("s1", 1), ("s2", 2), ("s3", 3)):
        assert main(["generate", "smoke", "-o", str(root / name), "--frames", "4", "--seed", str(seed)]) == 0
    return root


def _spec(folder: Path, trackers: str, rest: str = "", strategies: str = "[none, mask]") -> Path:
    path = folder / "spec.yaml"
    path.write_text(
        f"sweep: ext\nsequences: [{folder / 's1'}, {folder / 's2'}]\nstrategies: {strategies}\n"
        f"trackers:\n{trackers}{rest}"
    )
    return path


def _oracle(parameters: str = "{noise_m: 0.0, margin_px: 4, mode: ok}", extra: str = "") -> str:
    return f"  - name: oracle\n    command: {json.dumps(COMMAND)}\n    parameters: {parameters}\n{extra}"


def _rows(out: Path) -> list[dict[str, str]]:
    with (out / "results.csv").open() as handle:
        return list(csv.DictReader(handle))


def test_a_sweep_runs_an_external_program_over_its_parameters_and_detectors(
    sequences: Path, tmp_path: Path, capsys
):
    spec = _spec(
        sequences,
        _oracle(),
        "parameters:\n  oracle:\n    noise_m: {grid: [0.0, 0.02, 0.1]}\n"
        "detectors: [groundtruth, {detector: groundtruth, faults: {miss: 0.5, latency: 1}}]\n",
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    rows = [r for r in _rows(tmp_path / "sw") if r["tracker"] == "oracle"]
    assert len(rows) == 2 * 3 * 2 * 2  # sequences x noise x detectors x (none, mask)
    assert all(not r["failure"] for r in rows)
    ate = {}
    for r in rows:
        ate.setdefault(json.loads(r["parameters"])["noise_m"], []).append(float(r["ate_rmse_m"]))
    assert max(ate[0]) < 1e-6 < min(ate[0.1])  # the true trajectory, then perturbed
    assert sum(ate[0.02]) < sum(ate[0.1])  # parameters are stored as numbers
    clean = [r for r in rows if r["detector"] == "groundtruth" and r["strategy"] == "none"]
    assert all(r["rejection_recall"] not in ("", None) for r in clean)  # its decisions were scored
    faulted = [r for r in rows if r["detector"] != "groundtruth" and r["strategy"] == "none"]
    mean = lambda rs: sum(float(r["rejection_recall"] or 0) for r in rs) / len(rs)  # noqa: E731
    assert mean(faulted) < mean(clean)  # half the boxes missing reach its rejection
    capsys.readouterr()
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    assert "(24 already done)" in capsys.readouterr().out


def test_the_programs_keypoint_decisions_are_scored_against_the_exact_labels(sequences: Path, tmp_path: Path):
    """The recall in metrics.json recomputed by hand from the program's own keypoint file."""
    out = tmp_path / "run"
    args = ["run", str(sequences / "s1"), "-o", str(out), "--slam", "cmd", "--command", COMMAND]
    assert main([*args, "--param", "margin_px=6", "--param", "noise_m=0", "--param", "mode=ok"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    sequence = Sequence.open(sequences / "s1")
    objects = sequence.objects()
    frames = list(csv.DictReader((out / "frames.csv").open()))
    moving = rejected_moving = 0
    for i, frame in enumerate(frames):
        assert int(frame["keypoints"]) == len(range(8, 160, 16)) * len(range(8, 120, 16))
        moving += int(frame["moving_keypoints"])
        rejected_moving += int(frame["rejected_moving"])
        ids = {o.instance_id for o in objects[i] if o.moving}
        import numpy as np

        grid = np.array([(x, y) for x in range(8, 160, 16) for y in range(8, 120, 16)], float)
        assert int(true_moving_labels(sequence, i, grid, ids).sum()) == int(frame["moving_keypoints"])
    assert moving > 0 and metrics["rejection"]["recall"] == pytest.approx(rejected_moving / moving)
    assert metrics["tracker"] == "cmd" and metrics["parameters"]["margin_px"] == "6"
    assert (out / "program.log").is_file() and metrics["peak_memory_mb"] > 1
    # Issue 54 item 5: the report draws the program's keypoints from its decision file, as it
    # draws the built-in tracker's, and its legend names only the decisions the run made.
    import numpy as np

    with np.load(out / "diagnostics.npz") as d:
        assert [int(f["keypoints"]) for f in frames] == d["keypoint_counts"].tolist()
        starts = np.r_[0, np.cumsum(d["keypoint_counts"])]
        for i, frame in enumerate(frames):
            span = slice(starts[i], starts[i + 1])
            codes, on_mover = d["rejection"][span], d["moving"][span]
            assert int((codes == 1).sum()) == int(frame["rejected_keypoints"])
            assert int(((codes == 1) & on_mover).sum()) == int(frame["rejected_moving"])
        assert d["rejection_names"].tolist() == ["kept", "rejected"]
    assert main(["report", str(out), "-o", str(tmp_path / "page")]) == 0
    page = (tmp_path / "page" / "index.html").read_text()
    assert 'alt="frames with keypoints"' in page and "No frames to show" not in page
    legend = page[page.index("Top row, decision:") : page.index("Bottom row, truth:")]
    assert ">kept</span>" in legend and ">rejected</span>" in legend and "epipolar" not in legend


@pytest.mark.parametrize(
    ("mode", "reason"),
    [
        ("hang", "stopped after the time limit of 3 s"),
        ("flood", ""),
        ("fork", ""),
        ("exit3", "exited with code 3 (giving up: a deliberate failure)"),
        ("bad_trajectory", "trajectory.txt:3"),
        ("nan_keypoint", "keypoints.txt"),
        ("outside_keypoint", "is not inside the 160x120 image"),
    ],
)
def test_a_misbehaving_program_is_a_failed_row_and_leaves_no_process(
    sequences: Path, tmp_path: Path, mode: str, reason: str, monkeypatch
):
    token = f"oracle-{os.getpid()}-{mode}"
    monkeypatch.setenv("DEPOTBENCH_TEST_TOKEN", token)  # inherited by the program and its children
    spec = _spec(
        sequences,
        _oracle(f"{{noise_m: 0.0, margin_px: 4, mode: {mode}}}", "    timeout_s: 3\n"),
        strategies="[none]",
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw"), "--workers", "1"]) == 0
    rows = [r for r in _rows(tmp_path / "sw") if r["tracker"] == "oracle"]
    assert len(rows) == 2
    if mode in ("flood", "fork"):  # 1 GB printed, or a child left asleep: the run itself is fine
        assert all(not r["failure"] and float(r["ate_rmse_m"]) < 1e-6 for r in rows), rows
    else:
        assert all(reason in r["failure"] and r["ate_rmse_m"] == "" for r in rows), rows
    assert wait_until_gone(token) == []


@pytest.mark.parametrize(
    ("tracker", "needle"),
    [
        (
            _oracle().replace("{keypoints}", "{keypoint}"),
            "trackers.0 (oracle): --command: unknown placeholder {keypoint}",
        ),
        (
            "  - name: oracle\n    command: ./nowhere.sh {sequence}\n",
            "trackers.0 (oracle): --command: the program",
        ),
        (_oracle(extra="    settings: broken.j2\n"), "broken.j2:1: the settings template does not parse"),
        (_oracle(extra="    settings: unknown.j2\n"), "'nothing_like_this' is undefined"),
        ("  - {name: orb, kind: orbslam3, parameters: {ThDepth: -5}}\n", "ThDepth = -5 is out of range"),
        (
            "  - {name: orb, kind: orbslam3, parameters: {nFeatures: 5}}\n",
            "unknown ORB-SLAM3 parameter 'nFeatures'",
        ),
        ("  - {name: orb, kind: orbslam3, parameters: {pace: 11}}\n", "pace = 11 is out of range [0, 10]"),
    ],
)
def test_a_tracker_that_cannot_run_is_refused_before_any_run_naming_it(
    sequences: Path, tmp_path: Path, capsys, tracker: str, needle: str
):
    folder = tmp_path / "specs"
    folder.mkdir()
    for name in ("s1", "s2"):
        (folder / name).symlink_to(sequences / name)
    (folder / "broken.j2").write_text("{% if %}\n")
    (folder / "unknown.j2").write_text("fx: {{ camera.fx }}\nn: {{ nothing_like_this }}\n")
    (folder / "nowhere.sh").touch()  # there, but not executable
    assert main(["sweep", str(_spec(folder, tracker)), "-o", str(tmp_path / "sw")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "sw").exists()


def test_a_settings_template_reaches_the_program_rendered(sequences: Path, tmp_path: Path):
    template = tmp_path / "settings.j2"
    template.write_text(
        "%YAML:1.0\n{{ orbslam_camera }}\nWindow: {{ params['window'] }}\nfx_twice: {{ camera.fx * 2 }}\n"
    )
    copier = tmp_path / "copy.py"
    copier.write_text(
        "import shutil, sys\nshutil.copy(sys.argv[1], sys.argv[3])\n"
        "lines = [l for l in open(sys.argv[2]) if not l.startswith('#')]\n"
        "open(sys.argv[4], 'w').write(''.join(lines))\n"
    )
    seen = tmp_path / "seen.yaml"
    truth = shlex.quote(str(sequences / "s1" / "groundtruth.txt"))
    command = f"{sys.executable} {copier} {{settings}} {truth} {seen} {{trajectory}}"
    args = ["run", str(sequences / "s1"), "-o", str(tmp_path / "r"), "--slam", "cmd", "--command", command]
    assert main([*args, "--param", "window=7", "--settings-template", str(template)]) == 0
    text = seen.read_text()
    assert "Camera.fx: 131.25" in text and "Window: 7" in text and "fx_twice: 262.5" in text


def test_a_gate_names_the_external_tracker_and_its_parameters(sequences: Path, tmp_path: Path, capsys):
    gate = tmp_path / "g.yaml"
    gate.write_text(
        f"gates: ext\nrun:\n  sequences: [{sequences / 's1'}]\n  strategies: [none]\n  trackers:\n"
        + _oracle().replace("  - ", "    - ", 1).replace("\n    ", "\n      ")
        + "  parameters: {oracle: {noise_m: {grid: [0.0, 0.1]}}}\n"
        "checks:\n  - name: oracle-accurate\n    trackers: [oracle]\n    budgets: {ate_rmse_m: {max: 0.01}}\n"
    )
    assert main(["check", str(gate), "-o", str(tmp_path / "chk")]) == 1
    out = capsys.readouterr().out
    failed = [line for line in out.splitlines() if line.startswith("FAILED")]
    assert len(failed) == 1 and "oracle" in failed[0] and "noise_m=0.1" in failed[0], out


def test_a_changed_program_is_run_again_not_resumed(sequences: Path, tmp_path: Path, capsys):
    program = tmp_path / "oracle_copy.py"
    shutil.copyfile(ORACLE, program)
    command = COMMAND.replace(str(ORACLE), str(program))
    spec = _spec(sequences, f"  - name: oracle\n    command: {json.dumps(command)}\n", strategies="[none]")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    program.write_text(program.read_text() + "\n# rebuilt\n")
    capsys.readouterr()
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    out = capsys.readouterr().out
    # the script is in the key (probe O3: an edited script resumed its old rows)
    assert "(0 already done)" in out and "2 rows of tracker oracle fingerprint" in out


def test_processes_of_a_hung_program_do_not_outlive_the_sweep(sequences: Path, tmp_path: Path, monkeypatch):
    from multiprocessing import resource_tracker

    # The worker pool's resource tracker lives as long as this process: started here, under the
    # token, it was counted as left over whenever no earlier test in the process had started it.
    resource_tracker.ensure_running()
    token = f"oracle-{os.getpid()}-sweep"
    monkeypatch.setenv("DEPOTBENCH_TEST_TOKEN", token)
    spec = _spec(sequences, _oracle("{mode: fork}", "    timeout_s: 3\n"), strategies="[none]")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw"), "--workers", "2"]) == 0
    assert processes_with(token) == []


WRAPPER = REPO / "assets" / "examples" / "external" / "builtin_tracker.py"


@pytest.mark.slow  # 60 s; test_example_trackers.py checks the wrapper run by run in the default run
def test_the_built_in_tracker_through_the_protocol_gives_the_built_in_rows(sequences: Path, tmp_path: Path):
    """Issue 35 point 5, through the engine: the wrapped built-in tracker, handed the
    bench's boxes (faulted too) and parameters, scores the same ATE and rejection
    precision/recall as the built-in run, on 3 sequences with 2 strategies."""
    command = (
        f"{shlex.quote(sys.executable)} {WRAPPER} --sequence {{sequence}} --detections {{detections}} "
        "--parameters {parameters} --trajectory {trajectory} --keypoints {keypoints}"
    )
    faulted = "{detector: groundtruth, faults: {miss: 0.3, jitter: 0.1, false_positives: 0.5}}"
    listed = ", ".join(str(sequences / name) for name in ("s1", "s2", "s3"))
    for strategy in ("box_rule", "box_epipolar_flow"):
        spec = tmp_path / f"{strategy}.yaml"
        spec.write_text(
            f"sweep: wrapped\nsequences: [{listed}]\nstrategies: [none, {strategy}]\n"
            f"detectors: [groundtruth, {faulted}]\ntrackers:\n  - builtin\n  - name: wrapped\n"
            f"    command: {json.dumps(command)}\n    parameters: {{strategy: {strategy}}}\n"
        )
        out = tmp_path / f"sw-{strategy}"
        assert main(["sweep", str(spec), "-o", str(out), "--workers", "2"]) == 0
        rows = _rows(out)
        builtin = {
            (r["sequence"], r["detector"]): r
            for r in rows
            if r["tracker"] == "builtin" and r["strategy"] == strategy
        }
        wrapped = {
            (r["sequence"], r["detector"]): r
            for r in rows
            if r["tracker"] == "wrapped" and r["strategy"] == "none"
        }
        assert len(builtin) == len(wrapped) == 6
        for key, row in builtin.items():
            other = wrapped[key]
            assert not other["failure"], other["failure"]
            for column in ("ate_rmse_m", "tracked_fraction", "rejection_precision", "rejection_recall"):
                assert other[column] == row[column], (key, column, other[column], row[column])


def same(rows: list[dict]) -> list[str]:
    """Rows as comparable text, without what names the folder a sequence was generated in."""
    skip = ("key", "family", "sequence_fingerprint", "computed_by")
    return sorted(str({k: v for k, v in r.items() if k not in skip}) for r in rows)


@pytest.mark.slow
def test_an_external_sweep_is_the_same_with_ray_and_after_five_sigkills(tmp_path: Path):
    """Issue 35's done-when: a 4-sequence walking suite, the program x 3 values of a
    parameter x 2 detectors (faulted true boxes, and the ONNX model), with 2 workers and
    with Ray: identical rows; killed 5 times at random moments and resumed: row for row."""
    import signal
    import subprocess
    import time

    import numpy as np
    from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS
    from depotbench.eval.sweep.store import ResultStore

    pytest.importorskip("ray")
    (tmp_path / "walk.yaml").write_text(
        "suite: walk\nbase: smoke\noverrides: {frames: 6}\nseeds: [11, 12, 13, 14]\n"
    )
    (tmp_path / "spec.yaml").write_text(
        "sweep: ext\nsuite: walk.yaml\nstrategies: [none, mask]\ntrackers:\n"
        + _oracle("{noise_m: 0.0, margin_px: 4, mode: ok}")
        + "parameters: {oracle: {margin_px: {grid: [0, 4, 12]}}}\n"
        "detectors: [{detector: groundtruth, faults: {miss: 0.4, latency: 2}}, onnx]\n"
    )

    def table(out: Path) -> list[dict]:
        with ResultStore(out / "results.sqlite", readonly=True) as store:
            return [{k: r[k] for k in DETERMINISTIC_FIELDS if k != "sequence"} for r in store.rows()]

    def sweep(out: str, *extra: str) -> list[str]:
        return [
            sys.executable,
            "-m",
            "depotbench.eval.cli.main",
            "sweep",
            str(tmp_path / "spec.yaml"),
            "-o",
            out,
            *extra,
        ]

    env = {**os.environ, "DEPOTBENCH_CACHE": "off"}
    for out, extra in (("local", ()), ("ray", ("--backend", "ray"))):
        done = subprocess.run(
            sweep(str(tmp_path / out), "--workers", "2", *extra), env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
    reference = table(tmp_path / "local")
    assert len(reference) == 4 * 3 * 2 * 2 and all(r["failure"] is None for r in reference)
    ray = table(tmp_path / "ray")
    assert same(ray) == same(reference)
    rng = np.random.default_rng(35)
    for moment in rng.uniform(2.0, 8.0, 5):
        proc = subprocess.Popen(
            sweep(str(tmp_path / "killed"), "--workers", "2"),
            env=env,
            start_new_session=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(moment)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    resumed = subprocess.run(
        sweep(str(tmp_path / "killed"), "--workers", "2"), env=env, capture_output=True, text=True
    )
    assert resumed.returncode == 0, resumed.stderr
    assert same(table(tmp_path / "killed")) == same(reference)


@pytest.mark.slow  # 20 s
def test_a_search_over_a_programs_parameter_and_the_report_of_the_sweep(
    sequences: Path, tmp_path: Path, capsys
):
    """An Optuna search over the program's own parameter; the HTML report tracks the best
    external run again (its program found from the spec's folder) and says nothing is left out."""
    pytest.importorskip("optuna")
    spec = _spec(
        sequences,
        _oracle("{noise_m: 0.05, margin_px: 4, mode: ok}"),
        "search: {tracker: oracle, trials: 3, space: {noise_m: {low: 0.0, high: 0.1}}}\n",
        strategies="[none]",
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    out = capsys.readouterr().out
    summary = json.loads((tmp_path / "sw" / "summary.json").read_text())
    assert summary["search"]["tracker"] == "oracle" and summary["search"]["trials"] == 3
    assert "best oracle {'noise_m'" in out
    assert main(["report", str(tmp_path / "sw"), "-o", str(tmp_path / "rep")]) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err, captured.err
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "oracle" in page and "noise_m" in page


def test_tables_and_plots_name_the_parameters_a_sweep_varies_and_the_report_drills_into_the_best(
    sequences: Path, tmp_path: Path, capsys
):
    """What a 2-parameter sweep of ORB-SLAM3 showed (six parameters, two swept): labels
    cut to defaults, plots for unswept parameters with zigzag lines, and the page's best
    run drawn from another parameter setting."""
    from depotbench.eval.sweep.store import ResultStore
    from depotbench.eval.sweep.summary import configurations, threshold_figures

    spec = _spec(
        sequences,
        _oracle("{noise_m: 0.0, margin_px: 4, mode: ok}"),
        "parameters: {oracle: {noise_m: {grid: [0.0, 0.05]}, margin_px: {grid: [0, 8]}}}\n",
        strategies="[none]",
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    with ResultStore(tmp_path / "sw" / "results.sqlite", readonly=True) as store:
        configs = configurations(store.records())
    labels = {c["label"] for c in configs if c["tracker"] == "oracle"}
    assert labels == {f"oracle margin_px={m} noise_m={n} · none" for m in (0, 8) for n in (0, 0.05)}
    names = [name for name, _ in threshold_figures(configs)]
    assert names == ["oracle-none-margin_px", "oracle-none-noise_m"]  # not mode: it takes one value
    best = json.loads((tmp_path / "sw" / "summary.json").read_text())["best"]["smoke"]
    assert best["parameters"]["noise_m"] == 0
    capsys.readouterr()
    assert main(["report", str(tmp_path / "sw"), "-o", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    wanted = settings_text({k: best["parameters"][k] for k in sorted(best["parameters"])})
    assert f"smoke: best — oracle {wanted}" in page
