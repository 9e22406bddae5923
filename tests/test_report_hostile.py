"""``depotbench report`` on hostile and damaged inputs (reliability probe C4, C6, C10, M8, D6).

Each refused input ends in exit 2, one line on stderr naming the file (and the field or
line), no traceback and no report folder. A source sequence that is damaged or cannot be
found leaves out only the sections that need its frames, and says so: a note in the page
and one warning line. The unbounded reads run in a child process with an address-space cap
and a peak-memory bound.
"""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main

from tests.capped import MAX_RSS_MB, peak_rss_mb
from tests.conftest import REPO

pytestmark = pytest.mark.render

SWEEP_SPEC = "sweep: r\nsequences: [../seq]\nstrategies: [none, box_rule]\n"


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """seq/ (6 smoke frames), r1/ (its run), specs/r.yaml and sw/ (its sweep, run from base/,
    so that its rows store the sequence as ``specs/../seq``, relative to that directory)."""
    root = tmp_path_factory.mktemp("hostile")
    assert main(["generate", "smoke", "-o", str(root / "seq"), "--frames", "6"]) == 0
    assert main(["run", str(root / "seq"), "-o", str(root / "r1")]) == 0
    (root / "specs").mkdir()
    (root / "specs" / "r.yaml").write_text(SWEEP_SPEC)
    before = Path.cwd()
    os.chdir(root)
    try:
        assert main(["sweep", "specs/r.yaml", "-o", "sw", "--workers", "1"]) == 0
    finally:
        os.chdir(before)
    return root


@pytest.fixture
def copy(base: Path, tmp_path: Path) -> Path:
    """A private copy of ``base`` to damage."""
    shutil.copytree(base, tmp_path / "b", symlinks=True)
    return tmp_path / "b"


def refused(capfd, args: list[str], *needles: str) -> str:
    """Exit 2 and exactly one line on stderr holding every needle, no traceback."""
    code = main(args)
    err = capfd.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def set_rows(sweep: Path, sequence: str) -> None:
    """Store ``sequence`` as every row's sequence path (the form a writer may store)."""
    with sqlite3.connect(sweep / "results.sqlite") as db:
        db.execute("UPDATE runs SET sequence = ?", (sequence,))


# -- C10: malformed sweep and run folders -------------------------------------------------


@pytest.mark.parametrize(
    ("text", "needle"),
    [("{}", "configurations"), ("[1, 2]", "JSON object"), ('{"configurations": 3}', "configurations")],
)
def test_a_malformed_summary_is_refused_by_name(copy: Path, capfd, text: str, needle: str):
    (copy / "sw" / "summary.json").write_text(text)
    refused(capfd, ["report", str(copy / "sw"), "-o", str(copy / "out")], "summary.json", needle)
    assert not (copy / "out").exists()


def test_a_summary_entry_of_the_wrong_type_names_its_field(copy: Path, capfd):
    summary = json.loads((copy / "sw" / "summary.json").read_text())
    summary["configurations"][1]["ate_rmse_m"] = "oops"
    (copy / "sw" / "summary.json").write_text(json.dumps(summary))
    refused(
        capfd,
        ["report", str(copy / "sw"), "-o", str(copy / "out")],
        "summary.json",
        "configurations.1.ate_rmse_m",
    )
    assert not (copy / "out").exists()


def test_a_stored_spec_that_is_not_a_sweep_spec_is_refused_by_name(copy: Path, capfd):
    with sqlite3.connect(copy / "sw" / "results.sqlite") as db:
        db.execute("UPDATE meta SET value = ? WHERE name = 'spec'", ('{"sweep": 3, "strategies": "x"}',))
    refused(capfd, ["report", str(copy / "sw"), "-o", str(copy / "out")], "results.sqlite", "spec", "sweep")
    assert not (copy / "out").exists()


def test_frames_csv_shorter_than_the_diagnostics_is_refused_by_name(copy: Path, capfd):
    frames = copy / "r1" / "frames.csv"
    frames.write_text("".join(frames.read_text().splitlines(keepends=True)[:3]))
    refused(capfd, ["report", str(copy / "r1"), "-o", str(copy / "out")], "frames.csv", "2 frames", "6")
    assert not (copy / "out").exists()


def test_a_bad_line_of_frames_csv_is_named(copy: Path, capfd):
    frames = copy / "r1" / "frames.csv"
    lines = frames.read_text().splitlines(keepends=True)
    fields = lines[4].split(",")
    fields[1] = "flying"
    lines[4] = ",".join(fields)
    frames.write_text("".join(lines))
    refused(capfd, ["report", str(copy / "r1"), "-o", str(copy / "out")], "frames.csv:5", "flying")
    assert not (copy / "out").exists()


def test_inconsistent_diagnostics_are_refused_by_name(copy: Path, capfd):
    """Counts that do not add up to the keypoints would index past the arrays in the strip."""
    import numpy as np

    path = copy / "r1" / "diagnostics.npz"
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["keypoint_counts"] = arrays["keypoint_counts"] * 2
    np.savez_compressed(path, **arrays)
    refused(capfd, ["report", str(copy / "r1"), "-o", str(copy / "out")], "diagnostics.npz", "keypoint")
    assert not (copy / "out").exists()


# -- C4: unbounded reads, in a capped child ----------------------------------------------------


def _npy_header(shape: tuple[int, ...], dtype: str) -> bytes:
    """A version 1.0 .npy header declaring ``shape`` of ``dtype``."""
    text = repr({"descr": dtype, "fortran_order": False, "shape": shape}).encode()
    pad = 64 - (10 + len(text) + 1) % 64
    body = text + b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(body)) + body


def _bomb(path: Path) -> None:
    """diagnostics.npz whose keypoints_px declares 3 GiB (only 1 MiB of it is there)."""
    import numpy as np

    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, array in arrays.items():
            if name == "keypoints_px":
                archive.writestr(f"{name}.npy", _npy_header(((3 << 30) // 8, 2), "<f4") + bytes(1 << 20))
                continue
            with archive.open(f"{name}.npy", "w") as member:
                np.lib.format.write_array(member, array)


def _hostile_runs(root: Path) -> dict[str, tuple[Path, str]]:
    """A copy of r1 per unbounded read: (run folder, what the error line must name)."""
    cases = {}
    for name in ("frames-devzero", "metrics-2g", "npz-bomb"):
        shutil.copytree(root / "r1", root / name)
        cases[name] = root / name
    (root / "frames-devzero" / "frames.csv").unlink()
    (root / "frames-devzero" / "frames.csv").symlink_to("/dev/zero")
    (root / "metrics-2g" / "metrics.json").unlink()
    with (root / "metrics-2g" / "metrics.json").open("wb") as handle:
        handle.truncate(2 << 30)  # 2 GiB of holes
    _bomb(root / "npz-bomb" / "diagnostics.npz")
    return {
        "frames-devzero": (cases["frames-devzero"], "frames.csv: is not a regular file"),
        "metrics-2g": (cases["metrics-2g"], "metrics.json: is 2147483648 bytes, more than the 1 MiB limit"),
        "npz-bomb": (cases["npz-bomb"], "diagnostics.npz: declares more than the 2048 MiB limit"),
    }


def test_unbounded_run_files_are_refused_under_300_mb(copy: Path):
    """frames.csv -> /dev/zero, a 2 GiB metrics.json and a diagnostics.npz declaring a 3 GiB
    array: each refused in one line naming the file and the rule, within 300 MB."""
    peaks = {}
    for name, (run, needle) in _hostile_runs(copy).items():
        out = copy / f"out-{name}"
        code, err, peaks[name] = peak_rss_mb(["report", str(run), "-o", str(out)])
        lines = err.strip().splitlines()
        assert code == 2, f"{name}: exit {code}\n{err}"
        assert len(lines) == 1 and "Traceback" not in err, f"{name}:\n{err}"
        assert needle in lines[0], (name, lines[0])
        assert not out.exists(), name
    assert max(peaks.values()) < MAX_RSS_MB, peaks


# -- C6: a full disk under --rerun ----------------------------------------------------------------

_FSIZE = """
import resource, signal, subprocess, sys
size = int(sys.argv[1])
def limit():
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))
sys.exit(subprocess.run(sys.argv[2:], preexec_fn=limit).returncode)
"""
"""Runs a command that may write no file larger than the limit: a full disk, for one file."""


def test_rerun_on_a_full_disk_is_one_line_and_writes_nothing(copy: Path):
    pytest.importorskip("rerun")
    rrd, out = copy / "x.rrd", copy / "out"
    args = ["report", str(copy / "r1"), "-o", str(out), "--rerun", str(rrd)]
    proc = subprocess.run(
        [sys.executable, "-c", _FSIZE, str(100_000), sys.executable, "-m", "depotbench.eval.cli", *args],
        cwd=REPO,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},  # a .pyc cut short by the cap breaks imports
        capture_output=True,
        timeout=120,
    )
    err = proc.stderr.decode("utf-8", "replace")
    lines = err.strip().splitlines()
    assert proc.returncode == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "x.rrd" in lines[0] and "File too large" in lines[0], lines[0]
    assert not out.exists() and not rrd.exists()
    assert sorted(p.name for p in copy.iterdir() if p.name.startswith(".")) == []


# -- M8: a damaged source sequence ----------------------------------------------------------------


@pytest.mark.parametrize("parallel_frames", [300, 0], ids=["in this process", "in two workers"])
def test_a_sweep_over_a_damaged_sequence_is_reported_from_the_database(
    copy: Path, capfd, monkeypatch, parallel_frames: int
):
    """The frame file that cannot be read is named whether the featured runs are tracked again
    here or in worker processes (a FileError does not cross processes whole)."""
    monkeypatch.setattr("depotbench.eval.report.html.PARALLEL_FRAMES", parallel_frames)
    set_rows(copy / "sw", str(copy / "seq"))
    (copy / "seq" / "depth" / "1.100000.png").unlink()
    assert main(["report", str(copy / "sw"), "-o", str(copy / "out"), "--workers", "2"]) == 0
    err = capfd.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "warning" in lines[0] and "Traceback" not in err, err
    assert str(copy / "seq") in lines[0] and "1.100000.png" in lines[0], lines[0]
    page = (copy / "out" / "index.html").read_text()
    assert "Best configuration per family" in page and "Every configuration" in page
    assert "Left out" in page and "1.100000.png" in page
    assert "frames with keypoints" not in page  # the featured runs need the frames


# -- D6 / M10: stored relative sequence paths --------------------------------------------------------


def test_a_sequence_path_relative_to_the_sweep_folder_is_found_from_anywhere(
    base: Path, copy: Path, capfd, monkeypatch
):
    """The sweep ran on base/seq: its fingerprint holds that folder, so the rows name it."""
    set_rows(copy / "sw", os.path.relpath(base / "seq", copy / "sw"))
    (copy / "else" / "where").mkdir(parents=True)  # not as deep as sw/: the path means nothing here
    monkeypatch.chdir(copy / "else" / "where")
    assert main(["report", "../../sw", "-o", "../../out"]) == 0
    err = capfd.readouterr().err
    assert "warning" not in err, err
    page = (copy / "out" / "index.html").read_text()
    assert "Scenario difficulty" in page and "frames with keypoints" in page


def test_a_sequence_path_relative_to_the_working_directory_is_still_found(
    base: Path, copy: Path, capfd, monkeypatch
):
    """What 0.3.15 stored (``specs/../seq``: relative to where the sweep ran), read from there."""
    set_rows(copy / "sw", os.path.relpath(base / "seq", copy))
    monkeypatch.chdir(copy)
    assert main(["report", "sw", "-o", "out"]) == 0
    err = capfd.readouterr().err
    assert "warning" not in err, err
    page = (copy / "out" / "index.html").read_text()
    assert "Scenario difficulty" in page and "frames with keypoints" in page


def test_a_moved_sequence_is_tracked_again_and_a_changed_one_is_not_and_says_why(
    copy: Path, capfd, monkeypatch
):
    """copy/seq is a copy: the same files, so the same fingerprint (a sequence's key is its
    content, not its folder), and its featured runs are tracked again. Once a file of it is
    changed, its fingerprint is not the sweep's: left out, with the reason."""
    set_rows(copy / "sw", "specs/../seq")  # as 0.3.15 stored it, relative to where the sweep ran
    monkeypatch.chdir(copy)
    assert main(["report", "sw", "-o", "out"]) == 0
    assert capfd.readouterr().err == ""
    assert "not tracked again" not in (copy / "out" / "index.html").read_text()
    truth = copy / "seq" / "groundtruth.txt"
    truth.write_text(truth.read_text() + "\n")
    assert main(["report", "sw", "-o", "out2"]) == 0
    lines = capfd.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "warning" in lines[0] and "fingerprint" in lines[0], lines
    page = (copy / "out2" / "index.html").read_text()
    assert "Scenario difficulty" in page and "Left out" in page and "not tracked again" in page


def test_a_sequence_that_cannot_be_found_is_said_not_dropped(copy: Path, capfd, monkeypatch):
    set_rows(copy / "sw", "specs/../seq")  # as 0.3.15 stored it, relative to where the sweep ran
    (copy / "elsewhere").mkdir()
    monkeypatch.chdir(copy / "elsewhere")
    assert main(["report", "../sw", "-o", "../out"]) == 0  # neither beside sw/ nor from here
    lines = capfd.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "warning" in lines[0] and "specs/../seq" in lines[0], lines
    page = (copy / "out" / "index.html").read_text()
    assert "Left out" in page and "specs/../seq" in page and "not found" in page


def test_a_run_report_finds_its_sequence_or_names_it(copy: Path, capfd, monkeypatch):
    """metrics.json keeps the sequence as ``run`` was given it: here ``seq``, relative to copy/."""
    metrics = json.loads((copy / "r1" / "metrics.json").read_text())
    (copy / "r1" / "metrics.json").write_text(json.dumps({**metrics, "sequence": "seq"}))
    monkeypatch.chdir(copy)
    assert main(["report", "r1", "-o", "out1"]) == 0
    assert capfd.readouterr().err == ""
    assert "frames with keypoints" in (copy / "out1" / "index.html").read_text()
    (copy / "elsewhere").mkdir()
    monkeypatch.chdir(copy / "elsewhere")
    assert main(["report", "../r1", "-o", "../out2"]) == 0
    lines = capfd.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "warning" in lines[0] and "seq" in lines[0], lines
    page = (copy / "out2" / "index.html").read_text()
    assert "Left out" in page and "not found" in page


def test_a_spec_whose_detector_cannot_be_rebuilt_leaves_out_only_the_run_details(copy: Path, capfd):
    """The stored spec names files relative to a spec file the sweep folder does not keep
    (``onnx:models/x.onnx``): every result is still in the database."""
    with sqlite3.connect(copy / "sw" / "results.sqlite") as db:
        (stored,) = db.execute("SELECT value FROM meta WHERE name = 'spec'").fetchone()
        spec = {**json.loads(stored), "detectors": ["onnx:models/gone.onnx"]}
        db.execute("UPDATE meta SET value = ? WHERE name = 'spec'", (json.dumps(spec),))
    assert main(["report", str(copy / "sw"), "-o", str(copy / "out")]) == 0
    lines = capfd.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "warning" in lines[0] and "gone.onnx" in lines[0], lines
    page = (copy / "out" / "index.html").read_text()
    assert "Best configuration per family" in page and "Left out" in page and "gone.onnx" in page
