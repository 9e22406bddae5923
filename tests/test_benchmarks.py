"""The scripts in benchmarks/ still run: they print the figures the README and the issue
notes quote, and nothing else exercises them. A renamed function (generation.py's
``--stages`` times functions by name) or a changed signature breaks them silently."""

from __future__ import annotations

import importlib
import importlib.util
import re
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import REPO, benchmark_module

BENCHMARKS = REPO / "benchmarks"
SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py") if p.name != "sheets.py")  # sheets: a helper


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=300, check=False
    )


def _generation_module():
    return benchmark_module("generation")


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_benchmark_script_parses_its_arguments(script: str):
    result = _run(str(BENCHMARKS / script), "--help")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage:"), result.stdout[:200]


def test_every_stage_generation_times_names_a_function_that_exists():
    for label, module_name, attribute in _generation_module().STAGES:
        owner = importlib.import_module(module_name)
        for name in attribute.split("."):
            assert hasattr(owner, name), f"--stages {label!r}: {module_name}.{attribute} does not exist"
            owner = getattr(owner, name)
        assert callable(owner), f"{module_name}.{attribute}"


@pytest.mark.render
@pytest.mark.slow  # 10 s; the stage names are checked against the code by default
def test_generation_stages_prints_every_stage_with_its_time():
    small = ("--frames", "2", "--width", "80", "--height", "60")
    result = _run(str(BENCHMARKS / "generation.py"), "--stages", *small)
    assert result.returncode == 0, result.stderr
    # The default scenario has no sensor model and writes no gt/flow, so its flow is the moving
    # pixels' alone: a stage that never ran is not printed.
    unused = {"sensor model", "exact flow (sensor, gt/flow)"}
    labels = {label for label, _, _ in _generation_module().STAGES} - unused
    labels |= {"other", "frame loop"}
    for label in labels:
        assert re.search(rf"^  {re.escape(label)}\s+\d+\.\d\d", result.stdout, re.M), (label, result.stdout)


@pytest.mark.slow  # 60 s of rendering; generation_stages checks the benchmark script in the default run
@pytest.mark.render
def test_generation_peer_prints_mujoco_alone_and_the_ratio_of_the_same_run():
    """``--peer``: MuJoCo alone in two processes, and the two-process rate over it, which is
    the printed rates' quotient (to their rounding)."""
    small = ("--frames", "3", "--width", "80", "--height", "60", "--png-compression", "1")
    result = _run(str(BENCHMARKS / "generation.py"), "--peer", *small)
    assert result.returncode == 0, result.stderr
    double = re.search(r"^  2 processes:\s+(\d+\.\d)", result.stdout, re.M)
    peer = re.search(r"^  MuJoCo alone, 2 processes :\s+(\d+\.\d)", result.stdout, re.M)
    share = re.search(r"^  2 processes / MuJoCo alone:\s+(\d+\.\d\d)", result.stdout, re.M)
    assert double and peer and share, result.stdout
    rate, alone = float(double[1]), float(peer[1])
    assert alone > 0
    # Rates are printed to 0.05, the ratio to 0.005.
    assert float(share[1]) == pytest.approx(rate / alone, abs=0.006 + 0.06 / alone)


def test_generation_ceiling_is_mujoco_alones_core_time_over_the_formats_own_work():
    """Closed form: MuJoCo alone at 100 frames/s in two processes spends 20 ms of a core a
    frame; colour 10 + instance 5 + unoccluded 3 + deflate 7 = 25 ms leave room for at most
    0.8 of its rate, and with a 5 ms sensor model 20 / 30. Other stages do not count."""
    stages = {
        "colour pass (RGB and depth)": 10.0,
        "instance pass": 5.0,
        "unoccluded areas": 3.0,
        "deflate (writer threads)": 7.0,
        "sensor model": 5.0,
        "poses and physics": 4.0,
        "frame loop": 40.0,
    }
    ceiling = _generation_module().ceiling
    assert ceiling(100.0, stages) == pytest.approx((25.0, 0.8))
    assert ceiling(100.0, stages, ("sensor model",)) == pytest.approx((30.0, 20.0 / 30.0))


@pytest.mark.slow  # 15 s of rendering; the ceiling's arithmetic is checked in the default run
@pytest.mark.render
def test_generation_stages_with_peer_print_the_ceiling_of_their_own_figures():
    """``--stages --peer``: a breakdown per profile, then MuJoCo alone on the same world, and
    per profile the bound its printed stages and the printed peer give (to their rounding)."""
    small = ("--frames", "3", "--width", "80", "--height", "60", "--png-compression", "1")
    args = ("--stages", "--peer", "--scene", "walking_xyz", "--profiles", "perfect", "tum", *small)
    result = _run(str(BENCHMARKS / "generation.py"), *args)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    peer = re.search(r"^MuJoCo alone, 2 processes: (\d+\.\d) frames/s, (\d+\.\d\d) ms of a core", out, re.M)
    assert peer, out
    core_ms = float(peer[2])
    assert core_ms == pytest.approx(2e3 / float(peer[1]), abs=0.01 + 2e3 / float(peer[1]) ** 2 * 0.05)
    blocks = out.split("walking_xyz, sensor ")[1:]
    assert [b.split(",")[0] for b in blocks] == ["perfect", "tum"], out
    for block, profile in zip(blocks, ("perfect", "tum"), strict=True):
        figures = {
            m[1].strip(): float(m[2]) for m in re.finditer(r"^  (\S[^\d\n]*?)\s+(\d+\.\d\d)", block, re.M)
        }
        work = sum(figures[label] for label in _generation_module().FORMAT_WORK)
        line = re.search(
            rf"^  {profile}\s+the passes and deflate\s+(\d+\.\d\d) ms a frame: at most (\d\.\d\d)", out, re.M
        )
        assert line, out
        assert float(line[1]) == pytest.approx(work, abs=0.021)
        assert float(line[2]) == pytest.approx(core_ms / work, abs=0.006 + core_ms / work**2 * 0.02)
    assert re.search(r"^  tum\s+and the sensor model\s+\d+\.\d\d ms a frame: at most \d\.\d\d", out, re.M), (
        out
    )
    assert not re.search(r"^  perfect\s+and the sensor model", out, re.M), out


@pytest.mark.slow  # 9 s; the script's arguments are parsed in the default run, as every script's
@pytest.mark.render
def test_recognition_counts_what_a_tiny_run_sees():
    """Two frames of walking_xyz, seed 3 (its walkers in view at once): the people in view
    are counted (found <= seen) and every group of the issue's targets gets a line."""
    result = _run(
        str(BENCHMARKS / "recognition.py"),
        *("--scenes", "walking_xyz", "--seeds", "3", "--frames", "2", "--workers", "1"),
    )
    assert result.returncode == 0, result.stderr
    counts = re.findall(r"^recall standing[^(]*\((\d+)/(\d+);", result.stdout, re.M)
    assert counts, result.stdout
    assert all(0 <= int(found) <= int(seen) and int(seen) > 0 for found, seen in counts)
    for group in ("standing, whole", "standing, cut by the edge", "seated", "dog", "cat"):
        assert re.search(rf"^recall {re.escape(group)}\s", result.stdout, re.M), group
    assert re.search(r"^pig called person\s", result.stdout, re.M)


def test_the_strategies_table_takes_settings_as_the_command_line_does(tmp_path):
    """benchmarks/strategies.py --set k=2.5: its text is parsed into the setting's value (it
    handed the text on, and tracking refused it), and a bad one is one line."""
    from tests.sequences import write_sequence

    write_sequence(tmp_path / "seq", n=5)
    result = _run(str(BENCHMARKS / "strategies.py"), str(tmp_path / "seq"), "--set", "k=2.5")
    assert result.returncode == 0, result.stderr[-2000:]
    assert "prior_flow" in result.stdout and "box_epipolar_flow" in result.stdout
    bad = _run(str(BENCHMARKS / "strategies.py"), str(tmp_path / "seq"), "--set", "k=wide")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.strip().splitlines()[-1].endswith("--set: setting k='wide' is not a number")


_SECONDS = r"cpu\s+(\d+\.\d+) s  wall\s+(\d+\.\d+) s"


@pytest.mark.slow  # 17 s of ORB-SLAM3 at camera pace
@pytest.mark.render
def test_the_tracking_benchmark_times_orbslam3_at_each_pace_and_refuses_a_bad_one(tmp_path):
    """benchmarks/tracking.py feeds ORB-SLAM3 at each ``--orbslam3-pace`` in turn, here the
    stand-in wheel (tests/programs/stub_orbslam3) on 4 frames: a row and ratios per pace,
    and each run's whole cost beside its per-frame medians, consistent with them.

    The built-in runs alone on one core, so its CPU time cannot exceed its wall time, and
    its wall time holds every frame's tracking and mapping, which are timed inside it.
    ORB-SLAM3's worker is the stand-in's process: its whole CPU and wall time hold its
    start-up, which is taken off (never below 0)."""
    import os

    stub = REPO / "tests" / "programs" / "stub_orbslam3"
    path = os.pathsep.join([str(stub), *filter(None, [os.environ.get("PYTHONPATH")])])
    env = {**os.environ, "PYTHONPATH": path, "STUB_ORBSLAM3_CALLS": str(tmp_path / "calls.json")}
    args = ("--frames", "4", "--strategy", "none", "--orbslam3-pace", "0", "1", "--orbslam3-runs", "2",
            "--variant", "mapper_time_scale=1")  # fmt: skip
    result = subprocess.run([sys.executable, str(BENCHMARKS / "tracking.py"), *args], cwd=REPO, env=env,
                            capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    out = result.stdout
    header = next(line for line in out.splitlines() if line.startswith("tracker / strategy"))
    for column in ("tracking_total mean/med ms", "mapping mean/med ms", "track+map mean/med ms"):
        assert column in header, header
    assert header.endswith("whole sequence"), header

    row = re.search(r"^builtin none\s+(.*)$", out, re.M)
    assert row, out
    cells = re.findall(r"(\d+\.\d\d) /\s+(\d+\.\d\d)", row[1])
    assert len(cells) == 6, row[0]  # extract, reject, track, tracking_total, mapping, track+map
    means = [float(mean) for mean, _ in cells]
    assert means[3] == pytest.approx(sum(means[:3]), abs=0.02)  # tracking_total, to rounding
    assert means[5] == pytest.approx(means[3] + means[4], abs=0.02)  # track+map adds mapping
    cpu_s, wall_s = (float(x) for x in re.search(_SECONDS, row[1]).groups())
    assert 0 < cpu_s <= wall_s + 0.01  # one core: 10 ms for the clocks' granularity
    assert int(re.search(r"keyframes\s+(\d+)  ATE\s+[\d.]+ mm$", row[1])[1]) >= 1  # the first frame makes one
    # the variant: a row of its own, its ATE among the seeds' figures
    assert re.search(r"^builtin none mapper_time_scale=1\s+.*ATE\s+[\d.]+ mm$", out, re.M), out
    summary = r"^  builtin none mapper_time_scale=1\s+[\d.]+; [\d.]+ \[[\d.]+-[\d.]+\]$"
    assert re.search(summary, out, re.M), out
    # 4 frames asked; the analog's tum sensor may lose one, as TUM's driver did.
    frames = int(re.search(r"tracked 0/(\d+) frames", out)[1])
    assert 3 <= frames <= 4
    assert wall_s >= frames * means[5] / 1e3 - 0.001  # every frame's tracking and mapping, to rounding

    startup = re.search(rf"^orbslam3 start-up, no frame\s+{_SECONDS}$", out, re.M)
    assert startup and float(startup[1]) > 0 and float(startup[2]) > 0, out
    for pace in ("0", "1"):
        orbslam3 = re.search(
            rf"^orbslam3 none pace {pace}\s.*{_SECONDS}(?:  keyframes\s+\d+)?   tracked 0/{frames} frames; "
            rf"whole process cpu (\d+\.\d+) s, wall (\d+\.\d+) s$",
            out,
            re.M,
        )
        assert orbslam3, out
        runs = re.findall(
            rf"^orbslam3 none pace {pace}\s.*{_SECONDS}(?:  keyframes\s+\d+)?   tracked", out, re.M
        )
        assert len(runs) == 2, out  # --orbslam3-runs 2
        sequence_cpu, sequence_wall, whole_cpu, whole_wall = (float(x) for x in orbslam3.groups())
        assert 0 <= sequence_cpu <= whole_cpu and 0 <= sequence_wall <= whole_wall
        assert whole_cpu > 0 and whole_wall > 0
        median = re.search(rf"^orbslam3 none pace {pace}, median\s.*{_SECONDS}", out, re.M)
        assert median, out
        # the lower middle of two runs: the smaller, a figure one run measured
        assert float(median[1]) == min(float(cpu) for cpu, _ in runs)
        # beside it, the runs' spread: from the smaller CPU to the larger
        spread = re.search(
            rf"^orbslam3 none pace {pace}, median\s.*   2 runs: cpu ([\d.]+)-([\d.]+) s", out, re.M
        )
        assert spread, out
        assert [float(x) for x in spread.groups()] == sorted(float(cpu) for cpu, _ in runs)
        sequence_cpu = float(median[1])
        ratios = re.search(
            rf"^  built-in / orbslam3 pace {pace}\s+none: tracking ([\d.]+)x, track\+map ([\d.]+)x, "
            rf"cpu ([\d.]+|nan)x, wall ([\d.]+|nan)x, keyframes ([\d.]+|nan)x$",
            out,
            re.M,
        )
        assert ratios, out
        if sequence_cpu > 0.01:  # the ratio of the printed figures, to their rounding
            assert float(ratios[3]) == pytest.approx(cpu_s / sequence_cpu, rel=0.1, abs=0.01)
        for name in ("tracking", "track+map", "cpu", "wall", "keyframes"):
            x = r"(?:[\d.]+|nan)x"
            summary = rf"^  none\s+pace {pace}\s+{re.escape(name)}\s+{x}; {x} \[[\d.na]+-[\d.na]+\]$"
            assert re.search(summary, out, re.M), (name, out)
    bad = _run(str(BENCHMARKS / "tracking.py"), "--orbslam3-pace", "11")
    assert bad.returncode == 2 and bad.stderr.strip().splitlines()[-1].endswith(
        "--orbslam3-pace: orbslam3: pace = 11 is out of range [0, 10]"
    )


def test_the_tracking_benchmark_finds_stored_sequences_and_names_a_folder_without_one(tmp_path, capsys):
    """``--sequences`` takes sequence folders (meta.json inside) or folders holding them one
    level down, in name order; a folder with neither is refused as a bad argument is (exit 2,
    a line naming the script and the folder: it exited 1), and ``--seed`` beside
    ``--sequences`` is refused (the seeds would be ignored)."""
    import argparse

    tracking = benchmark_module("tracking")
    for name in ("b", "a"):
        (tmp_path / "suite" / name).mkdir(parents=True)
        (tmp_path / "suite" / name / "meta.json").write_text("{}", encoding="utf-8")
    (tmp_path / "empty").mkdir()
    single = tmp_path / "suite" / "b"
    parser = argparse.ArgumentParser(prog="mapping_costs.py")  # the other script that reads them
    assert tracking._stored([tmp_path / "suite", single], parser) == [
        tmp_path / "suite" / "a",
        tmp_path / "suite" / "b",
        single,
    ]
    capsys.readouterr()
    with pytest.raises(SystemExit) as refused:
        tracking._stored([tmp_path / "empty"], parser)
    assert refused.value.code == 2
    assert re.search(
        r"^mapping_costs.py: error: --sequences .*empty: no meta.json there or one level down$",
        capsys.readouterr().err,
        flags=re.M,
    )
    both = _run(str(BENCHMARKS / "tracking.py"), "--sequences", str(single), "--seed", "1")
    assert both.returncode == 2 and both.stderr.strip().splitlines()[-1].endswith(
        "--sequences and --seed: give one"
    )


def _has_commit(rev: str) -> bool:
    return (
        subprocess.run(
            ["git", "-C", str(REPO), "cat-file", "-e", f"{rev}^{{commit}}"], check=False
        ).returncode
        == 0
    )


@pytest.mark.slow  # 20 s
@pytest.mark.render
def test_sweep_benchmark_times_this_code_and_the_code_before_issue_40():
    """sweep.py on a toy sweep (1 sequence of 3 frames, 2 configurations): its modes run (the
    settings went in as text until they were typed, and it crashed), and ``--baseline`` runs
    the same sweep with depotbench imported from the revision's files (settings as that code
    took them, its cache switch), then prints the speed-up over it; below each of this code's
    modes, the seconds of each phase that ran."""
    module = benchmark_module("sweep")
    if not _has_commit(module.BEFORE_ISSUE_40):
        pytest.skip(f"this clone lacks commit {module.BEFORE_ISSUE_40}")
    toy = ("--frames", "3", "--seeds", "1", "--configs", "2", "--workers", "1", "--skip-naive")
    result = _run(str(BENCHMARKS / "sweep.py"), *toy, "--baseline")
    assert result.returncode == 0, result.stderr[-2000:]
    out = result.stdout
    assert re.search(r"^  \| depotbench from .*depotbench-baseline-.*/tree$", out, re.M), out
    assert re.search(r"^  \| cache \+ dedupe\s+\d+\.\d s \(2 tracked, 1 shared\)$", out, re.M), out
    assert re.search(r"^cache \+ dedupe\s+\d+\.\d s .*\(2 tracked, 1 shared\)$", out, re.M), out
    assert re.search(r"^cache\s+\d+\.\d s .*\(3 tracked, 0 shared\)$", out, re.M), out
    # each mode's phases, the decision paths where jobs are deduplicated (the child's older engine times none)
    phases = re.findall(r"^  of which (.*)$", out, re.M)
    number = r"\d+\.\d s"
    assert len(phases) == 2, out
    assert re.fullmatch(
        rf"the shared stages {number}, the decision paths {number}, tracking {number}", phases[0]
    )
    assert re.fullmatch(rf"the shared stages {number}, tracking {number}", phases[1])
    assert re.search(
        rf"^speed-up of cache \+ dedupe over revision {module.BEFORE_ISSUE_40}: \d+\.\d\dx", out, re.M
    )


def test_sweep_benchmark_refuses_a_baseline_that_is_not_a_commit_in_one_line():
    result = _run(str(BENCHMARKS / "sweep.py"), "--baseline", "no-such-revision")
    assert result.returncode == 2
    assert result.stderr.strip() == "sweep.py: --baseline no-such-revision: not a commit of this repository"
    assert result.stdout == ""  # refused before any sequence is generated


def _columns(lines: list[str]) -> list[int]:
    """The right edges of the header's words (where right-aligned figures below must end)."""
    return [m.end() for m in re.finditer(r"\S+(?: \S+)*", lines[0])]


def test_the_cli_help_table_lines_up_each_figure_under_its_header():
    text = benchmark_module("cli_help").table(
        {"depotbench --help": [100.0, 120.0, 110.0], "x": [200.0, 330.0]}
    )
    lines = text.splitlines()
    assert lines[0].split() == ["command", "median", "ms", "fastest", "x", "peer"]
    assert set(lines[1]) <= {"-", " "}
    assert lines[2].split()[-3:] == ["110", "100", "1.0"] and lines[3].split() == ["x", "265", "200", "2.4"]
    edges = _columns(lines)[1:]
    for line in lines[2:]:
        assert [m.end() for m in re.finditer(r"\S+", line)][-3:] == edges


def test_the_actor_views_table_counts_each_heading_and_all():
    module = benchmark_module("actor_views")
    crop = np.zeros((1, 1, 3), np.uint8)
    views = [
        module.View(1, 0.0, 1.0, 0.9, "cat", crop),
        module.View(2, 0.0, 1.0, 0.1, "dog", crop),
        module.View(1, 90.0, 1.0, 0.2, "dog", crop),
        module.View(2, 90.0, 1.0, 0.7, "cat", crop),
    ]
    lines = module.report(views, "cat").splitlines()
    assert lines[0].startswith("heading") and "called instead" in lines[0]
    assert [line.split()[:3] for line in lines[2:]] == [
        ["0°", "1/2", "0.50"],
        ["90°", "1/2", "0.45"],
        ["all", "2/4", "0.47"],
    ]
    assert lines[2].rstrip().endswith("dog 1") and "(recognised per seed 0.50-0.50)" in lines[4]


def test_the_mapping_cost_fit_recovers_known_coefficients():
    """benchmarks/mapping_costs.py fits each step's milliseconds to its terms: on rows made
    from known coefficients (no noise) it returns them, R^2 1 and no error; the total is the
    rows' sum."""
    fit = benchmark_module("mapping_costs")._fit
    rng = np.random.default_rng(5)
    terms = np.c_[np.ones(40), rng.uniform(0, 500, 40), rng.uniform(0, 1e4, 40)]
    truth = np.array([2.5, 0.02, 3e-4])
    coefficients, r2, error, total = fit([(row, float(row @ truth)) for row in terms])
    np.testing.assert_allclose(coefficients, truth, rtol=1e-9)
    assert r2 == pytest.approx(1.0) and error == pytest.approx(0.0, abs=1e-9)
    assert total == pytest.approx(float((terms @ truth).sum()))
