"""Hostile inputs to `export-dataset` and `detect-eval` (the reliability probe's S1, D8, M3, D13,
D2 and M6): each is refused with exit 2 and one line naming the file, before anything is
written, and the input stays as it was."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.eval.cli.main import main

from tests.conftest import REPO
from tests.sequences import write_sequence
from tests.test_output import one_error_line, snapshot

FRAME = "rgb/1.000000.png"
"""The first RGB frame of a sequence from ``write_sequence`` (64 x 48, random pixels: about 9 KB)."""


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-frame generated sequence, made once; tests copy it before they damage it."""
    root = tmp_path_factory.mktemp("made") / "seq"
    write_sequence(root, n=4, with_flow=False)
    return root


@pytest.fixture
def seq(made: Path, tmp_path: Path) -> Path:
    """A private copy of the sequence, at ``tmp_path / 'seq'``."""
    return Path(shutil.copytree(made, tmp_path / "seq", symlinks=True))


def refused(tmp: Path, capfd, args: list[str], *needles: str) -> str:
    """Run the CLI; exit 2, one line naming ``needles``, nothing printed, nothing written."""
    before = snapshot(tmp)
    listing = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*"))
    assert main(args) == 2
    out, err = capfd.readouterr()
    line = one_error_line(err, *needles)
    assert line.startswith(f"depotbench {args[0]}: error: "), line
    assert out == "", "the command did work before it refused"
    assert snapshot(tmp) == before, "the input changed"
    assert sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*")) == listing, "something was written"
    return line


def a_png(path: Path, width: int = 64, height: int = 48) -> bytes:
    """A valid RGB PNG the size of the sequence's frames: it passes every image check."""
    image = np.full((height, width, 3), 200, np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), image)
    return path.read_bytes()


def list_first_frame_as(seq: Path, name: str) -> None:
    """Make line 1 of associations.txt name ``name`` as its RGB frame."""
    assoc = seq / "associations.txt"
    lines = assoc.read_text().splitlines()
    fields = lines[0].split()
    fields[1] = name
    lines[0] = " ".join(fields)
    assoc.write_text("\n".join(lines) + "\n")


# -- S1: symbolic links out of the sequence folder ------------------------------------------------


def test_export_refuses_a_frame_linked_to_a_file_outside_the_sequence(seq: Path, tmp_path: Path, capfd):
    # The secret is a valid PNG of the right size, so only the link check can stop it.
    a_png(tmp_path / "private" / "secret.png")
    (seq / FRAME).unlink()
    (seq / FRAME).symlink_to("../../private/secret.png")
    args = ["export-dataset", str(seq), "-o", str(tmp_path / "ds")]
    line = refused(tmp_path, capfd, args, FRAME, "a link out of the sequence folder")
    assert "secret.png" in line  # where the link leads


@pytest.mark.parametrize("target", ["private", "/"])
def test_export_refuses_a_frame_reached_through_a_folder_link(seq: Path, tmp_path: Path, capfd, target: str):
    # The probe's case: x/root -> / and x/root/etc/passwd listed as a frame; and a folder
    # link to a valid PNG, which no image check would stop.
    a_png(tmp_path / "private" / "frame.png")
    (seq / "x").mkdir()
    (seq / "x" / "root").symlink_to(tmp_path / "private" if target == "private" else Path("/"))
    name = "x/root/frame.png" if target == "private" else "x/root/etc/passwd"
    list_first_frame_as(seq, name)
    args = ["export-dataset", str(seq), "-o", str(tmp_path / "ds")]
    refused(tmp_path, capfd, args, name, "a link out of the sequence folder")


def test_export_follows_links_that_stay_inside_the_sequence(seq: Path, tmp_path: Path, capsys):
    """A link within the folder reads nothing from elsewhere: it is exported as its target."""
    (seq / "copies").mkdir()
    shutil.move(seq / FRAME, seq / "copies" / "first.png")
    (seq / FRAME).symlink_to("../copies/first.png")
    assert main(["export-dataset", str(seq), "-o", str(tmp_path / "ds")]) == 0
    image = tmp_path / "ds" / "images" / "train" / "seq_1.000000.png"
    assert image.read_bytes() == (seq / "copies" / "first.png").read_bytes()
    capsys.readouterr()


def test_export_refuses_an_objects_file_linked_outside_the_sequence(seq: Path, tmp_path: Path, capfd):
    """The labels come from gt/objects.jsonl: it too must come from the sequence folder."""
    shutil.move(seq / "gt" / "objects.jsonl", tmp_path / "objects.jsonl")
    (seq / "gt" / "objects.jsonl").symlink_to(tmp_path / "objects.jsonl")
    args = ["export-dataset", str(seq), "-o", str(tmp_path / "ds")]
    refused(tmp_path, capfd, args, str(seq / "gt" / "objects.jsonl"), "a link out of the sequence folder")


@pytest.mark.parametrize("link", [FRAME, "rgb"])
def test_a_link_swapped_in_after_the_check_is_not_followed(seq: Path, tmp_path: Path, monkeypatch, link: str):
    """The frame is opened component by component with O_NOFOLLOW: a link that appears between
    the resolve-and-check and the open (a file link, or a folder link above the file) is refused."""
    from depotbench.core.errors import FileError
    from depotbench.eval.detection import dataset

    a_png(tmp_path / "private" / "1.000000.png")
    if link == "rgb":
        shutil.rmtree(seq / "rgb")
        (seq / "rgb").symlink_to(tmp_path / "private")
    else:
        (seq / FRAME).unlink()
        (seq / FRAME).symlink_to(tmp_path / "private" / "1.000000.png")
    monkeypatch.setattr(dataset, "_check_inside", lambda root, path: path)  # checked before the swap
    real = seq.resolve()
    with pytest.raises(FileError, match="became a link while it was read"):
        dataset.read_inside(real, real / FRAME)


# -- D8: frames that are not the sequence's images ------------------------------------------------


@pytest.mark.parametrize(
    ("damage", "needle"),
    [
        (lambda path: path.write_bytes(b"GIF89a-not-a-png"), "is not a PNG image"),
        (lambda path: path.write_bytes(path.read_bytes()[:2000]), "cannot be decoded"),
        (lambda path: a_png(path, 32, 24), "image is 32x24, the camera is 64x48"),
    ],
    ids=["gif", "truncated", "wrong-size"],
)
def test_export_refuses_a_frame_that_run_would_refuse(seq: Path, tmp_path: Path, capfd, damage, needle):
    damage(seq / FRAME)
    args = ["export-dataset", str(seq), "-o", str(tmp_path / "ds")]
    refused(tmp_path, capfd, args, str(seq / FRAME), needle)


# -- M3: a full disk names the output --------------------------------------------------------------

_FULL_DISK = """
import resource, signal, sys
from depotbench.eval.cli.main import main
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit then fails with EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]), resource.RLIM_INFINITY))
sys.exit(main(sys.argv[2:]))
"""
"""A child whose files may not grow beyond argv[1] bytes: the kernel refuses the real write,
as a full disk does (there with ENOSPC), without root or a small file system."""


def test_export_on_a_full_disk_names_the_dataset_not_the_input(seq: Path, tmp_path: Path):
    before = snapshot(seq)
    out = tmp_path / "ds"
    proc = subprocess.run(
        [sys.executable, "-c", _FULL_DISK, "4096", "export-dataset", str(seq), "-o", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
    )
    assert proc.returncode == 2, proc.stderr
    line = one_error_line(proc.stderr, str(out), "File too large")
    assert str(seq) not in line, line
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    assert snapshot(seq) == before


# -- D13: one sequence given twice -----------------------------------------------------------------


def test_detect_eval_refuses_a_sequence_given_twice(seq: Path, tmp_path: Path, capfd, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = ["detect-eval", "seq", "seq", "./seq/", "--detector", "groundtruth", "--min-pixels", "1"]
    refused(tmp_path, capfd, args, "seq", "given twice")


# -- D2 and M6: the -o file (the JSON report) --------------------------------------------------

EVAL = ["detect-eval", "--detector", "groundtruth", "--min-pixels", "1"]


def test_detect_eval_json_keeps_an_existing_file_unless_told(seq: Path, tmp_path: Path, capfd):
    notes = tmp_path / "notes.txt"
    notes.write_text("mine\n")
    refused(tmp_path, capfd, [*EVAL, str(seq), "-o", str(notes)], str(notes), "--overwrite")
    assert main([*EVAL, str(seq), "-o", str(notes), "--overwrite"]) == 0
    assert '"frames": 4' in notes.read_text()
    capfd.readouterr()


@pytest.mark.parametrize("inside", ["groundtruth.txt", "new.json"])
def test_detect_eval_json_never_writes_into_an_input(seq: Path, tmp_path: Path, capfd, inside: str):
    target = seq / inside
    args = [*EVAL, str(seq), "-o", str(target), "--overwrite"]
    refused(tmp_path, capfd, args, str(target), "inside the input")


@pytest.mark.parametrize(
    ("where", "needle"),
    [
        ("afile/sub/x.json", "afile"),
        ("afile/x.json", "afile"),
        ("/proc/x.json", "/proc"),
        ("folder", "is a folder"),
    ],
)
def test_detect_eval_json_refuses_an_unwritable_place_before_any_work(
    seq: Path, tmp_path: Path, capfd, where: str, needle: str
):
    (tmp_path / "afile").write_text("x\n")
    (tmp_path / "folder").mkdir()
    target = Path(where) if where.startswith("/") else tmp_path / where
    refused(tmp_path, capfd, [*EVAL, str(seq), "-o", str(target), "--overwrite"], str(target), needle)
