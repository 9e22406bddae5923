"""Output safety: no command ever loses or corrupts what a user had (issue: reliability).

Each test here reproduces a way data was lost or silently wrong, and failed
before outputs were staged, marked, locked and checked against the inputs.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from depotbench.core.output import (
    MARKER_NAME,
    OutputContainer,
    OutputError,
    OutputKind,
    OutputLock,
    StagedOutput,
    exchange,
    lock_path,
    read_marker,
)
from depotbench.eval.cli.main import main

from tests.conftest import REPO
from tests.sequences import write_sequence


def cli(capsys, *args: str) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` with its bytes (hidden ones included)."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def one_error_line(err: str, *needles: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


@pytest.fixture
def sequence(tmp_path: Path) -> Path:
    """A small synthetic sequence written by the real writer."""
    root = tmp_path / "seq"
    write_sequence(root, n=4)
    return root


# -- the building blocks -----------------------------------------------------------------


def test_staged_output_appears_complete_and_marked_or_not_at_all(tmp_path: Path):
    target = tmp_path / "out"
    with pytest.raises(RuntimeError, match="boom"), StagedOutput(target, OutputKind.RUN) as out:
        (out.path / "half.txt").write_text("half")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []  # no staging folder, no lock file
    with StagedOutput(target, OutputKind.RUN) as out:
        (out.path / "result.txt").write_text("new")
        assert not target.exists()
        out.commit()
    assert (target / "result.txt").read_text() == "new"
    assert read_marker(target).kind is OutputKind.RUN
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_overwrite_replaces_only_our_own_output_of_the_same_kind(tmp_path: Path):
    user = tmp_path / "photos"
    user.mkdir()
    (user / "holiday.jpg").write_bytes(b"precious")
    with pytest.raises(OutputError, match="not written by depotbench"):
        StagedOutput(user, OutputKind.RUN, overwrite=True).__enter__()
    assert (user / "holiday.jpg").read_bytes() == b"precious"
    a_file = tmp_path / "notes.txt"
    a_file.write_text("keep")
    with pytest.raises(OutputError, match="is a file"):
        StagedOutput(a_file, OutputKind.RUN, overwrite=True).__enter__()
    assert a_file.read_text() == "keep"
    sequence = tmp_path / "seq"
    write_sequence(sequence, n=2)
    with pytest.raises(OutputError, match="is a depotbench sequence output, not a run output"):
        StagedOutput(sequence, OutputKind.RUN, overwrite=True).__enter__()
    with pytest.raises(OutputError, match="already exists"):
        StagedOutput(sequence, OutputKind.SEQUENCE).__enter__()
    empty = tmp_path / "empty"
    empty.mkdir()
    with StagedOutput(empty, OutputKind.RUN) as out:  # an empty folder holds nothing to lose
        out.commit()
    assert read_marker(empty) is not None


def test_no_output_at_the_working_directory_its_ancestors_or_the_inputs(tmp_path: Path, monkeypatch):
    work = tmp_path / "work"
    (work / "sub").mkdir(parents=True)
    monkeypatch.chdir(work / "sub")
    for target in (Path("."), Path(".."), tmp_path, Path("/")):
        with pytest.raises(OutputError, match="current directory"):
            StagedOutput(target, OutputKind.RUN, overwrite=True).__enter__()
    source = tmp_path / "data" / "seq"
    source.mkdir(parents=True)
    for target, what in (
        (source, "is the input"),
        (tmp_path / "data", "holding the input"),
        (source / "results", "inside the input"),
    ):
        with pytest.raises(OutputError, match=what):
            StagedOutput(target, OutputKind.RUN, overwrite=True, inputs=(source,)).__enter__()


def test_exchange_swaps_two_folders_in_one_step(tmp_path: Path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "A").write_text("a")
    (tmp_path / "b" / "B").write_text("b")
    if not exchange(tmp_path / "a", tmp_path / "b"):
        pytest.skip("this file system cannot exchange folders atomically")
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["B"]
    assert [p.name for p in (tmp_path / "b").iterdir()] == ["A"]


def test_without_exchange_a_kill_between_the_renames_is_undone(tmp_path: Path, monkeypatch):
    import depotbench.core.output as output

    target = tmp_path / "out"
    with StagedOutput(target, OutputKind.RUN) as out:
        (out.path / "r.txt").write_text("old")
        out.commit()
    # Two-rename swap killed after the first rename: the old output sits aside, nothing at the target.
    aside = tmp_path / ".out.old-deadbeef"
    os.rename(target, aside)
    partial = tmp_path / ".out.partial-cafecafe"
    partial.mkdir()
    monkeypatch.setattr(output, "exchange", lambda a, b: False)
    with StagedOutput(target, OutputKind.RUN, overwrite=True) as out:
        assert (target / "r.txt").read_text() == "old"  # put back before anything else
        assert not aside.exists() and not partial.exists()
        (out.path / "r.txt").write_text("new")
        out.commit()
    assert (target / "r.txt").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


HOLD_LOCK = """
import sys, time
from pathlib import Path
from depotbench.core.output import OutputLock
OutputLock(Path(sys.argv[1])).acquire()
print("held", flush=True)
time.sleep(120)
"""


def hold_lock(target: Path) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD_LOCK, str(target)], cwd=REPO, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_writer_is_refused_by_name_and_a_dead_holders_lock_is_free(
    sequence: Path, tmp_path: Path, capsys
):
    target = tmp_path / "run"
    holder = hold_lock(target)
    try:
        code, _, err = cli(capsys, "run", sequence, "-o", target, "--detector", "none")
        assert code == 2
        one_error_line(err, str(target), f"pid {holder.pid}", "another depotbench is writing it")
        assert not target.exists()
    finally:
        holder.kill()
        holder.wait()
    assert lock_path(target).exists()  # the dead holder's lock file stays behind, unlocked
    code, _, err = cli(capsys, "run", sequence, "-o", target, "--detector", "none")
    assert code == 0, err
    assert not lock_path(target).exists() and read_marker(target).kind is OutputKind.RUN


def test_lock_file_swapped_under_a_waiting_writer_is_not_trusted(tmp_path: Path):
    target = tmp_path / "out"
    first = OutputLock(target)
    first.acquire()
    with pytest.raises(OutputError, match=f"pid {os.getpid()}"):
        OutputLock(target).acquire()
    first.release()
    second = OutputLock(target)
    second.acquire()  # the file was unlinked on release: a fresh one is made and locked
    assert lock_path(target).exists()
    second.release()


def test_container_refuses_a_foreign_folder_and_reuses_its_own(tmp_path: Path):
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("x")
    with pytest.raises(OutputError, match="not written by depotbench"):
        OutputContainer(foreign, OutputKind.SUITE).__enter__()
    with OutputContainer(tmp_path / "suite", OutputKind.SUITE) as box:
        (box.path / "a").mkdir()
    with OutputContainer(tmp_path / "suite", OutputKind.SUITE) as box:
        assert (box.path / "a").is_dir() and (box.path / MARKER_NAME).is_file()
    with pytest.raises(OutputError, match="is a depotbench suite output, not a demo output"):
        OutputContainer(tmp_path / "suite", OutputKind.DEMO).__enter__()


# -- the reproductions of the issue, through the command line ------------------------------------


def test_run_into_the_working_directory_is_refused_and_nothing_is_emptied(
    sequence: Path, monkeypatch, capsys
):
    folder = sequence.parent
    before = snapshot(folder)
    monkeypatch.chdir(folder)
    code, _, err = cli(capsys, "run", "seq", "-o", ".", "--overwrite", "--detector", "none")
    assert code == 2
    one_error_line(err, "is the current directory")
    assert snapshot(folder) == before


def test_run_onto_its_own_input_is_refused(sequence: Path, capsys):
    before = snapshot(sequence)
    for target in (sequence, sequence.parent):
        code, _, err = cli(capsys, "run", sequence, "-o", target, "--overwrite", "--detector", "none")
        assert code == 2
        one_error_line(err, str(target))
    assert snapshot(sequence) == before


def test_overwrite_onto_a_file_or_a_foreign_folder_is_refused(sequence: Path, tmp_path: Path, capsys):
    a_file = tmp_path / "results.csv"
    a_file.write_text("1,2,3\n")
    code, _, err = cli(capsys, "run", sequence, "-o", a_file, "--overwrite", "--detector", "none")
    assert code == 2 and a_file.read_text() == "1,2,3\n"
    one_error_line(err, str(a_file), "is a file")
    foreign = tmp_path / "experiments"
    foreign.mkdir()
    (foreign / "notes.md").write_text("keep me")
    code, _, err = cli(capsys, "run", sequence, "-o", foreign, "--overwrite", "--detector", "none")
    assert code == 2 and (foreign / "notes.md").read_text() == "keep me"
    one_error_line(err, "not written by depotbench")


def test_unwritable_output_is_found_before_any_work(sequence: Path, tmp_path: Path, capsys, monkeypatch):
    import depotbench.slam.system

    def no_work(*args, **kwargs):
        raise AssertionError("the SLAM ran before the output was checked")

    monkeypatch.setattr(depotbench.slam.system.Slam, "process", no_work)
    a_file = tmp_path / "plain-file"
    a_file.write_text("")
    for target in (a_file / "run", Path("/proc/depotbench-cannot-write/run")):
        code, _, err = cli(capsys, "run", sequence, "-o", target, "--detector", "none")
        assert code == 2
        one_error_line(err, str(target))


def test_a_rerun_replaces_its_output_atomically_and_cleans_killed_writers_leftovers(
    sequence: Path, tmp_path: Path, capsys
):
    target = tmp_path / "run"
    assert cli(capsys, "run", sequence, "-o", target, "--detector", "none")[0] == 0
    old = snapshot(target)
    stale = tmp_path / ".run.partial-0badc0de"
    stale.mkdir()
    (stale / "trajectory.txt").write_text("half")
    assert cli(capsys, "run", sequence, "-o", target, "--detector", "none")[0] == 2  # no --overwrite
    assert snapshot(target) == old
    code, _, err = cli(capsys, "run", sequence, "-o", target, "--detector", "none", "--overwrite")
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "seq"]


def test_preview_never_overwrites_a_file_unasked(sequence: Path, tmp_path: Path, capsys):
    png = tmp_path / "p.png"
    png.write_bytes(b"user's picture")
    code, _, err = cli(capsys, "preview", sequence, "-o", png)
    assert code == 2 and png.read_bytes() == b"user's picture"
    one_error_line(err, "already exists")
    assert cli(capsys, "preview", sequence, "-o", png, "--overwrite")[0] == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_eval_json_holds_only_json_numbers(tmp_path: Path, capsys):
    gt = tmp_path / "gt.txt"
    est = tmp_path / "est.txt"
    rows = [f"{1 + 0.1 * k:.6f} {k * 0.1} {k % 2 * 0.05} 0 0 0 0 1" for k in range(10)]
    gt.write_text("\n".join(rows) + "\n")
    est.write_text("\n".join(rows) + "\n")
    code, out, _ = cli(capsys, "eval", gt, est, "--json")
    assert code == 0
    json.loads(out, parse_constant=lambda name: pytest.fail(f"{name} in --json output"))
    huge = tmp_path / "huge.txt"
    huge.write_text("\n".join(f"{1 + 0.1 * k:.6f} {k * 1e200} 0 0 0 0 0 1" for k in range(10)) + "\n")
    code, _, err = cli(capsys, "eval", gt, huge, "--json")
    assert code == 2
    one_error_line(err, f"{huge}:2", "beyond")


def test_validated_specs_generate_including_a_top_down_camera(tmp_path: Path, capsys):
    """Specs that validated and then crashed ``generate``: now refused, or generated correctly."""
    import numpy as np
    from depotbench.sim.sequence import Sequence

    spec = tmp_path / "top.yaml"
    spec.write_text(
        "name: top\nframes: 2\nimage: {width: 160, height: 120}\nintrinsics: {fx: 131.25}\n"
        "layout: {props: 0, desk: false, rack_rows: 0}\n"
        "camera: {position_m: [0, 0, 3], target_m: [0, 0, 0]}\n"
    )
    code, _, err = cli(capsys, "generate", spec, "-o", tmp_path / "top")
    assert code == 0, err
    seq = Sequence.open(tmp_path / "top")
    pose = seq.world_from_camera(0)
    assert np.allclose(pose[:3, 2], [0, 0, -1], atol=0.01)  # looks straight down
    depth = seq.depth_m(0)
    assert abs(float(depth[60, 80]) - pose[2, 3]) < 0.01  # the floor, camera height away
    refused = {
        "above.yaml": ("camera: {position_m: [0, 0, 5], target_m: [0, 0, 0]}", "camera.position_m"),
        "same.yaml": ("camera: {position_m: [0, 0, 2], target_m: [0, 0, 2]}", "camera.target_m"),
        "twice.yaml": ("actors: [{kind: person, waypoints: [[1, 1], [1, 1]]}]", "actors.0.waypoints"),
        "inf.yaml": ("intrinsics: {fx: .inf}", "intrinsics.fx"),
        "wide.yaml": ("intrinsics: {fx: 0.001}", "intrinsics.fx"),
    }
    for name, (body, field) in refused.items():
        path = tmp_path / name
        path.write_text(f"name: x\nframes: 2\n{body}\n")
        for command in ("validate", "generate"):
            args = (command, path) if command == "validate" else (command, path, "-o", tmp_path / "o")
            code, _, err = cli(capsys, *args)
            assert code == 2, (name, command)
            one_error_line(err, str(path), field)
    assert not (tmp_path / "o").exists()


def test_command_line_values_obey_the_spec_limits(tmp_path: Path, capsys):
    for option, value, needle in (
        ("--seed", "-1", "greater than or equal to 0"),
        ("--frames", "100001", "less than or equal to 100000"),
        ("--frames", "0", "greater than or equal to 1"),
    ):
        code, _, err = cli(capsys, "generate", "smoke", "-o", tmp_path / "x", option, value)
        assert code == 2
        one_error_line(err, f"{option} {value}", needle)
    assert not (tmp_path / "x").exists()


def test_contradictory_settings_are_refused(sequence: Path, tmp_path: Path, capsys):
    code, _, err = cli(
        capsys, "run", sequence, "-o", tmp_path / "r", "--set", "min_depth_m=4", "--set", "max_depth_m=3"
    )
    assert code == 2
    one_error_line(err, "min_depth_m", "max_depth_m")


def test_paths_in_the_lists_must_stay_inside_the_sequence(sequence: Path, tmp_path: Path, capsys):
    outside = tmp_path / "outside.png"
    shutil.copy(next((sequence / "rgb").iterdir()), outside)
    assoc = sequence / "associations.txt"
    lines = assoc.read_text().splitlines()
    for bad in ("../outside.png", str(outside), "rgb/../../outside.png"):
        fields = lines[1].split()
        fields[1] = bad
        assoc.write_text("\n".join([lines[0], " ".join(fields), *lines[2:]]) + "\n")
        code, _, err = cli(capsys, "run", sequence, "-o", tmp_path / "r", "--detector", "none")
        assert code == 2
        one_error_line(err, "associations.txt:2", "outside the sequence folder")


@pytest.mark.render
def test_a_changed_suite_regenerates_what_changed_and_keeps_the_rest(tmp_path: Path, capsys):
    suite = tmp_path / "speeds.yaml"
    body = "suite: speeds\nbase: smoke\noverrides: {{frames: 2}}\ngrid:\n  actors.0.speed_mps: [{speeds}]\n"
    suite.write_text(body.format(speeds="0.6, 0.9"))
    out = tmp_path / "out"
    assert cli(capsys, "generate", suite, "-o", out, "--workers", "1")[0] == 0
    kept = (out / "speeds-0001" / "meta.json").stat().st_mtime_ns
    suite.write_text(body.format(speeds="1.4, 0.9"))
    code, _, err = cli(capsys, "generate", suite, "-o", out, "--workers", "1")
    assert code == 0, err
    index = json.loads((out / "index.json").read_text())
    for entry in index["sequences"]:
        meta = json.loads((out / entry["name"] / "meta.json").read_text())
        assert meta["scenario"]["actors"][0]["speed_mps"] == entry["knobs"]["actors.0.speed_mps"]
        assert read_marker(out / entry["name"]).content_key == entry["content_key"]
    assert (out / "speeds-0001" / "meta.json").stat().st_mtime_ns == kept  # unchanged, not redone


def test_suite_expansion_is_counted_before_it_is_built(tmp_path: Path, capsys):
    suite = tmp_path / "huge.yaml"
    grid = "\n".join(f"  knob{k}: [{', '.join(str(v) for v in range(20))}]" for k in range(8))
    suite.write_text(f"suite: huge\nbase: smoke\ngrid:\n{grid}\n")
    started = time.perf_counter()
    code, _, err = cli(capsys, "validate", suite)
    assert code == 2
    one_error_line(err, str(suite), "25600000000 sequences", "limit of 10000")
    assert time.perf_counter() - started < 30  # it used to take minutes and 5 GB; generous bound


@pytest.mark.render
@pytest.mark.parametrize(
    ("how", "settle_s"),
    [("ctrl-c", 1.0), ("sigterm", 1.0), ("ctrl-c", 0.0)],
    ids=["ctrl-c", "sigterm", "ctrl-c-at-start"],
)
def test_interrupting_a_suite_stops_its_workers_at_once_with_one_line(
    tmp_path: Path, how: str, settle_s: float
):
    """Ctrl-C reaches the whole process group; SIGTERM (``timeout``, a cancelled CI job) the
    parent alone. Either way the workers are stopped mid-sequence, not waited for. At start,
    a worker still importing once printed its own KeyboardInterrupt traceback."""
    suite = tmp_path / "s.yaml"
    suite.write_text("suite: s\nbase: smoke\noverrides: {frames: 900}\nseeds: [1, 2, 3, 4]\n")
    token = f"depotbench-test-{os.getpid()}-{time.time_ns()}"
    out = tmp_path / "o"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "depotbench.eval.cli",
            "generate",
            str(suite),
            "-o",
            str(out),
            "--workers",
            "2",
        ],
        cwd=REPO,
        env={**os.environ, "DEPOTBENCH_TEST_TOKEN": token},
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        start_new_session=True,
        # As from a terminal: a test run started in the background (``make test &``) has
        # SIGINT ignored, and an ignored signal stays ignored across exec.
        preexec_fn=_default_sigint,
    )
    deadline = time.time() + 60
    while time.time() < deadline and len(processes_with(token, exclude=proc.pid)) < 2:
        time.sleep(0.1)  # wait for the workers to start
    time.sleep(settle_s)  # and to be well into their first sequences (each takes tens of seconds)
    signalled = time.perf_counter()
    if how == "ctrl-c":
        os.killpg(proc.pid, signal.SIGINT)
    else:
        proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    stopped_after_s = time.perf_counter() - signalled
    assert proc.returncode == (130 if how == "ctrl-c" else 143), err
    word = "interrupted" if how == "ctrl-c" else "terminated"
    expected = f"depotbench generate: {word}; finished outputs are kept and nothing is half-written"
    assert err.strip() == expected
    assert wait_until_gone(token) == []
    assert not out.exists()  # no sequence was finished, and the suite folder made for them is gone
    assert stopped_after_s < 20, stopped_after_s  # generous: finishing one sequence takes ~40 s


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def processes_with(token: str, exclude: int | None = None) -> list[int]:
    """PIDs of live processes whose environment holds ``token`` (zombies do not count)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) in (os.getpid(), exclude):
            continue
        try:
            if (entry / "stat").read_text().split(") ")[-1].startswith("Z"):
                continue
            if token.encode() in (entry / "environ").read_bytes():
                found.append(int(entry.name))
        except OSError:
            continue
    return found


def wait_until_gone(token: str, timeout_s: float = 15.0) -> list[int]:
    deadline = time.time() + timeout_s
    while (alive := processes_with(token)) and time.time() < deadline:
        time.sleep(0.1)
    return alive


def test_leftovers_of_a_name_with_glob_characters_are_found(tmp_path: Path):
    target = tmp_path / "run[1]*"
    stale = tmp_path / ".run[1]*.partial-0badc0de"
    stale.mkdir()
    other = tmp_path / ".run1x.partial-0badc0de"  # what the unescaped pattern would also match
    other.mkdir()
    with StagedOutput(target, OutputKind.RUN) as out:
        out.commit()
    assert not stale.exists() and other.exists()


def test_a_container_cleans_its_outputs_leftovers_unless_a_live_writer_owns_them(tmp_path: Path):
    """A suite whose sequences are all complete writes none of them again, so it cleans
    what killed workers left beside them itself, but never under a live writer."""
    from depotbench.core.output import clean_if_unowned

    done, busy = tmp_path / "s-0000", tmp_path / "s-0001"
    for target in (done, busy):
        with StagedOutput(target, OutputKind.SEQUENCE) as out:
            out.commit()
        (tmp_path / f".{target.name}.partial-0badc0de").mkdir()
    holder = hold_lock(busy)
    try:
        assert clean_if_unowned(done) and clean_if_unowned(busy) is False
        assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == [
            ".s-0001.lock",
            ".s-0001.partial-0badc0de",
        ]
    finally:
        holder.kill()
        holder.wait()
    assert clean_if_unowned(busy)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s-0000", "s-0001"]


@pytest.fixture
def python_sigint():
    """Python's own Ctrl-C handler, as in a run from a terminal: a test run started in the
    background from a script (``pytest &``, nohup) inherits SIGINT ignored, and then no
    Ctrl-C can reach the code under test."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def test_ctrl_c_while_workers_are_spawned_interrupts_the_parent(python_sigint):
    """While the parent spawns workers, a Ctrl-C must still interrupt it: it used to
    ignore SIGINT in that window, and a Ctrl-C then was lost (the suite ran to the end
    with exit code 0: the ctrl-c-at-start case above, on CI). A worker starts with
    SIGINT blocked, so it cannot die of one while starting, and ignores it once
    released."""
    from depotbench.core.processes import children_block_sigint

    with children_block_sigint():
        child = subprocess.run(
            [
                sys.executable,
                "-c",
                "import signal; from depotbench.core.processes import release_sigint; "
                "mask = lambda: signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, set()); "
                "print(mask(), end=' '); release_sigint(); "
                "print(mask(), signal.getsignal(signal.SIGINT) == signal.SIG_IGN)",
            ],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        )
    assert child.stdout.split() == ["True", "False", "True"]

    with pytest.raises(KeyboardInterrupt):
        with children_block_sigint():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
        time.sleep(0.05)  # the handler runs between bytecodes once the signal is let through
        pytest.fail("the Ctrl-C sent while workers were spawned was lost")
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_ctrl_c_taken_by_another_thread_waits_until_the_workers_are_spawned(python_sigint):
    """Ctrl-C reaches the process group and any thread not blocking SIGINT may take it;
    Python then ran the handler in the main thread at once, in the middle of spawning a
    worker, which died reading its start-up data with a traceback ("Ran out of input":
    the ctrl-c-at-start case above, on a busy machine). The interrupt must wait for the
    window to close, and must not be lost."""
    from depotbench.core.processes import children_block_sigint

    release = threading.Event()
    other = threading.Thread(target=release.wait)  # started before the window: SIGINT not blocked
    other.start()
    spawned = False
    try:
        with pytest.raises(KeyboardInterrupt):
            with children_block_sigint():
                signal.pthread_kill(other.ident, signal.SIGINT)
                time.sleep(0.1)  # the handler would have run here, between bytecodes
                spawned = True
            time.sleep(0.05)
            pytest.fail("the Ctrl-C taken by another thread was lost")
    finally:
        release.set()
        other.join()
    assert spawned
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.parametrize("how", ["symbolic link", "hard link"])
def test_a_lock_file_planted_as_a_link_is_refused_and_its_target_untouched(
    sequence: Path, tmp_path: Path, capsys, how: str
):
    """Probe S2: `.NAME.lock -> ../precious.txt` was truncated and the holder's JSON written
    into its target."""
    precious = tmp_path / "precious.txt"
    precious.write_text("precious user data\n")
    out = tmp_path / "out"
    out.mkdir()
    if how == "symbolic link":
        (out / ".victim.lock").symlink_to(precious)
    else:
        os.link(precious, out / ".victim.lock")
    code, _, err = cli(capsys, "run", sequence, "-o", out / "victim", "--detector", "none")
    assert code == 2
    one_error_line(err, ".victim.lock", "remove it")
    assert precious.read_text() == "precious user data\n"
    assert not (out / "victim").exists()


def _gate(tmp_path: Path, sequence: Path) -> Path:
    path = tmp_path / "g.yaml"
    path.write_text(
        f"gates: g\nrun:\n  sequences: [{sequence}]\n  strategies: [none]\n"
        "checks:\n  - name: c\n    budgets: {ate_rmse_m: {max: 1}}\n"
    )
    return path


def _no_run(monkeypatch) -> None:
    def refuse(*args, **kwargs):
        raise AssertionError("the matrix ran before the output was checked")

    monkeypatch.setattr("depotbench.eval.gates.check.run_gates", refuse)


@pytest.mark.parametrize(
    ("target", "needle"),
    [
        ("g.yaml", "is the input"),
        ("seq/groundtruth.txt", "lies inside the input"),
        ("notes.txt", "already exists (pass --overwrite"),
        ("afile/j.xml", "is not a folder"),
        ("afile/sub/j.xml", "Not a directory"),
        ("/proc/j.xml", "/proc"),
    ],
)
def test_a_junit_file_that_must_not_or_cannot_be_written_is_refused_before_the_run(
    sequence: Path, tmp_path: Path, capsys, monkeypatch, target: str, needle: str
):
    """Probe D2 (`check --junit` replaced the gate file, an input's groundtruth.txt or any
    file) and M6 (an unwritable place was found after the whole matrix had run)."""
    gate = _gate(tmp_path, sequence)
    (tmp_path / "notes.txt").write_text("mine\n")
    (tmp_path / "afile").write_text("x")
    before = snapshot(tmp_path)
    _no_run(monkeypatch)
    junit = target if target.startswith("/") else tmp_path / target
    code, _, err = cli(capsys, "check", gate, "-o", tmp_path / "chk", "--junit", junit)
    assert code == 2
    one_error_line(err, "--junit", needle)
    assert snapshot(tmp_path) == before and not (tmp_path / "chk").exists()


def test_a_junit_file_is_replaced_when_asked_and_written_whole(sequence: Path, tmp_path: Path, capsys):
    gate = _gate(tmp_path, sequence)
    junit = tmp_path / "gates.xml"
    junit.write_text("old\n")
    code, out, _ = cli(capsys, "check", gate, "-o", tmp_path / "chk", "--junit", junit, "--overwrite")
    assert code in (0, 1) and f"wrote {junit}" in out  # the verdict aside, the file is written
    assert junit.read_text().startswith("<?xml")


def test_a_vocabulary_that_cannot_be_written_is_refused_before_it_is_built(
    tmp_path: Path, capsys, monkeypatch
):
    """Probe M6 `vocab-nodir`: about 4 minutes of building, then 'cannot write the output'.
    A missing folder is made first; a file where the folder should be is refused."""

    def refuse(*args, **kwargs):
        raise AssertionError("the vocabulary was built before its file was checked")

    monkeypatch.setattr("depotbench.eval.trackers.vocabulary.build_file", refuse)
    (tmp_path / "afile").write_text("x")
    code, _, err = cli(capsys, "vocab", "-o", tmp_path / "afile" / "v.txt", "--scenes", "smoke")
    assert code == 2
    one_error_line(err, "afile", "is not a folder")


def test_a_junit_file_in_a_folder_a_clean_clone_lacks_is_written(sequence: Path, tmp_path: Path, capsys):
    """docs/ci-example.yml writes `--junit reports/gates.xml` from a clean clone."""
    gate, reports = _gate(tmp_path, sequence), tmp_path / "reports"
    code, _, _ = cli(capsys, "check", gate, "-o", tmp_path / "chk", "--junit", reports / "g.xml")
    assert code in (0, 1) and (reports / "g.xml").read_text().startswith("<?xml")


def test_a_sweep_or_gate_output_inside_an_input_sequence_is_refused(sequence: Path, tmp_path: Path, capsys):
    """Probe D12: `sweep in.yaml -o seq/results` wrote into the input sequence folder."""
    before = snapshot(sequence)
    spec = tmp_path / "in.yaml"
    spec.write_text(f"sweep: in\nsequences: [{sequence}]\nstrategies: [none]\n")
    code, _, err = cli(capsys, "sweep", spec, "-o", sequence / "results")
    assert code == 2
    one_error_line(err, "lies inside the input")
    code, _, err = cli(capsys, "check", _gate(tmp_path, sequence), "-o", sequence / "results")
    assert code == 2
    one_error_line(err, "lies inside the input")
    assert snapshot(sequence) == before


def test_an_output_name_as_long_as_the_system_allows_is_written(sequence: Path, tmp_path: Path, capsys):
    """Probe M9 `longname-240-run`: the hidden `.NAME.partial-XXXXXXXX` sibling went past
    the 255-byte limit of a name, and the run failed with 'File name too long'."""
    for length in (240, 255):
        out = tmp_path / ("r" * length)
        code, _, err = cli(capsys, "run", sequence, "-o", out, "--detector", "none")
        assert code == 0, err
        assert (out / "metrics.json").is_file()
        assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
