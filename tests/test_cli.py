"""The command line as a user meets it: output, JSON, and one-line errors with exit 2."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.metrics.trajectory import read_tum

from tests.evo_reference import evo_ape, evo_rpe

EXAMPLES = Path(__file__).resolve().parents[1] / "assets" / "examples"
GT = EXAMPLES / "fr1_xyz_groundtruth.txt"
EST = EXAMPLES / "fr1_xyz_rgbdslam.txt"


@pytest.mark.slow
def test_demo_generates_sweeps_gates_and_reports(capsys, tmp_path: Path):
    """The README's main job end to end (make demo runs exactly this)."""
    assert main(["demo", "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for name in ("results.sqlite", "results.csv", "summary.json", "gates.xml", "report/index.html"):
        assert (tmp_path / name).is_file(), name
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert len(summary["best"]) == 3  # 0, 6 and 12 people
    assert "all budgets held" in out


def test_report_table_and_rho():
    from depotbench.eval.report.table import format_table, summarise

    def metrics(ate, precision=None):
        return {
            "ate_m": {"rmse": ate},
            "tracked_frames": 10,
            "frames": 10,
            "rejection": {"precision": precision, "recall": 0.5},
            "stage_time": {"tracking_total": {"mean_ms": 20.0}},
        }

    rows = summarise({"crowd": {"none": metrics(0.2), "box_rule": metrics(0.05, 0.3)}})
    assert rows[1]["rho_percent"] == pytest.approx(75.0)
    table = format_table(rows).splitlines()
    assert len({len(line) for line in table}) == 1  # columns line up, missing values included


def test_eval_json_matches_evo(capsys):
    assert (
        main(
            [
                "eval",
                str(GT),
                str(EST),
                "--json",
                "--rpe-delta",
                "0.1",
                "--rpe-unit",
                "m",
                "--align",
                "sim3",
            ]
        )
        == 0
    )
    report = json.loads(capsys.readouterr().out)
    ref, est = read_tum(GT), read_tum(EST)
    expected_ate = evo_ape(ref, est, "sim3")
    expected_rpe = evo_rpe(ref, est, 0.1, "m", False, "trans", "sim3")
    assert report["associated_pairs"] == 786
    for key in ("rmse", "mean", "median", "std", "min", "max", "sse"):
        assert report["ate_m"][key] == pytest.approx(expected_ate[key], rel=1e-6)
        assert report["rpe_translation_m"][key] == pytest.approx(expected_rpe[key], rel=1e-6)


def test_eval_table(capsys):
    assert main(["eval", str(GT), str(EST), "--all-pairs", "--rpe-delta", "5"]) == 0
    out = capsys.readouterr().out
    assert "ATE (m)" in out and "RPE rot (deg)" in out and "5 frames, all pairs" in out


def test_bad_trajectory_line_is_named(tmp_path: Path, capsys):
    bad = tmp_path / "est.txt"
    bad.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 nan 0 0 0 1\n")
    assert main(["eval", str(GT), str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"depotbench eval: error: {bad}:3: pose holds NaN or infinity"


def test_missing_file_and_no_overlap(tmp_path: Path, capsys):
    assert main(["eval", str(GT), str(tmp_path / "none.txt")]) == 2
    assert "none.txt: file is missing" in capsys.readouterr().err
    shifted = tmp_path / "shifted.txt"
    shifted.write_text("1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n")
    assert main(["eval", str(GT), str(shifted)]) == 2
    assert "no timestamps" in capsys.readouterr().err


def test_console_script_and_module_entry_point():
    exe = shutil.which("depotbench", path=str(Path(sys.executable).parent))
    assert exe is not None, "the console script is not installed next to this Python"
    result = subprocess.run([exe, "eval", str(GT), str(EST)], capture_output=True, text=True)
    assert result.returncode == 0 and "0.013473" in result.stdout
    result = subprocess.run([exe, "eval", str(GT)], capture_output=True, text=True)
    assert result.returncode == 2 and "estimate" in result.stderr


@pytest.mark.slow  # 9 s
def test_png_compression_changes_file_sizes_not_pixels(tmp_path: Path, capsys):
    """`generate --png-compression 0` writes the same pixels as the default level, in larger
    files; a level outside 0-9 is refused before anything is written."""
    from depotbench.sim.sequence import Sequence

    for level in ("0", "1"):
        assert (
            main(
                [
                    "generate",
                    "default",
                    "--frames",
                    "2",
                    "-o",
                    str(tmp_path / level),
                    "--png-compression",
                    level,
                ]
            )
            == 0
        )
    fast, small = Sequence.open(tmp_path / "0"), Sequence.open(tmp_path / "1")
    for k in range(2):
        assert (fast.rgb(k) == small.rgb(k)).all() and (fast.depth_raw(k) == small.depth_raw(k)).all()
        assert fast.frames[k].rgb_path.stat().st_size > 1.5 * small.frames[k].rgb_path.stat().st_size
    with pytest.raises(SystemExit) as exit_info:
        main(["generate", "default", "--frames", "2", "-o", str(tmp_path / "bad"), "--png-compression", "10"])
    assert exit_info.value.code == 2
    assert "--png-compression: must be a zlib level 0-9, got '10'" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def _default_sigint() -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)  # as from a terminal (a background run ignores it)


_STARTER = (
    "import sys\nimport depotbench.eval.cli.main\nsys.stderr.write('started\\n')\nsys.stderr.flush()\n"
    "sys.argv = ['depotbench', *sys.argv[1:]]\ndepotbench.eval.cli.main.entry()\n"
)
"""The program as the console script starts it, saying when depotbench's module is loaded:
from there on a Ctrl-C is depotbench's to report (before it, Python's own start-up is
running, 0.05 s here and more under load)."""


@pytest.mark.parametrize("delay_s", [0.05, 0.15, 0.3, 0.45])
def test_ctrl_c_while_the_command_line_starts_is_one_line(tmp_path: Path, delay_s: float):
    """Probe C15: a Ctrl-C in the first seconds, while the parser imported the library,
    gave a 19-24 line KeyboardInterrupt traceback; inside MuJoCo's or SciPy's extension
    modules it became "ImportError: initialization failed". The delays fall in the half
    second of imports that follows."""
    import signal
    import time

    from tests.conftest import REPO

    proc = subprocess.Popen(
        [sys.executable, "-c", _STARTER, "generate", "smoke", "-o", str(tmp_path / "g"), "--frames", "300"],
        cwd=REPO,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        preexec_fn=_default_sigint,
    )
    assert proc.stderr.readline() == "started\n"
    time.sleep(delay_s)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "g").exists()


def test_the_command_line_names_the_png_level_it_defaults_to():
    from depotbench.core.files import DEFAULT_PNG_COMPRESSION
    from depotbench.eval.cli.main import DEFAULT_PNG_COMPRESSION_LEVEL

    assert DEFAULT_PNG_COMPRESSION_LEVEL == DEFAULT_PNG_COMPRESSION


@pytest.mark.parametrize("value", ["0", "-1", "two", "257", "1.5"])
def test_a_bad_default_worker_count_is_one_line_naming_the_variable(
    monkeypatch, capsys, tmp_path: Path, value: str
):
    """Read where a command takes its default --workers: one line naming the variable there,
    and nothing for a command given --workers or asked for its --help."""
    monkeypatch.setenv("DEPOTBENCH_WORKERS", value)
    sweep = ["sweep", "nowhere.yaml", "-o", str(tmp_path / "sw")]
    assert main(sweep) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"depotbench sweep: error: DEPOTBENCH_WORKERS={value!r}: give the default worker count, 1 to 256"
    ]
    assert main([*sweep, "--workers", "1"]) == 2  # the spec is missing; the variable is not read
    assert "DEPOTBENCH_WORKERS" not in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:
        main(["sweep", "--help"])
    assert done.value.code == 0
    assert not (tmp_path / "sw").exists()


def test_the_default_worker_count_is_the_variable_or_the_cores_this_process_may_use(monkeypatch):
    """os.cpu_count() counts the host's cores: under taskset or a container's cpuset limited to
    one core of several, it started a worker per host core."""
    import os

    from depotbench.eval.cli.args import one_per_core
    from depotbench.eval.cli.main import build_parser

    monkeypatch.setenv("DEPOTBENCH_WORKERS", "3")
    assert one_per_core() == 3
    assert build_parser().parse_args(["sweep", "s.yaml", "-o", "o"]).workers is None  # read at run time
    assert build_parser().parse_args(["sweep", "s.yaml", "-o", "o", "--workers", "2"]).workers == 2
    monkeypatch.delenv("DEPOTBENCH_WORKERS")
    assert one_per_core() == len(os.sched_getaffinity(0))
    script = "from depotbench.eval.cli.args import one_per_core; print(one_per_core())"
    env = {k: v for k, v in os.environ.items() if k != "DEPOTBENCH_WORKERS"}
    pinned = subprocess.run(
        ["taskset", "-c", "0", sys.executable, "-c", script],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    )
    assert pinned.stdout.strip() == "1"
