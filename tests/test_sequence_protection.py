"""A program cannot change the sequence it is handed (O4 of reliability-probe-2.md).

``{sequence}`` is a view whose root files are private copies: a program rewriting
``{sequence}/groundtruth.txt`` changes only its copy, and its run fails naming the file.
A program that reaches the original (through a linked folder, or by path) fails naming the
file too. Later runs are scored against the true ground truth: a program that answers
with the true poses (kept aside before any run) gets an ATE of zero.
"""

from __future__ import annotations

import json
import shlex
import shutil
import sys
from pathlib import Path

import pytest
from depotbench.sim.sequence import Sequence

from tests.sequences import write_sequence
from tests.test_output import cli, one_error_line

SWAP_XY = """
import sys
from pathlib import Path
truth = Path(sys.argv[1]) / "groundtruth.txt"
Path(sys.argv[2]).write_text(truth.read_text())
lines = []
for line in truth.read_text().splitlines():
    words = line.split()
    if words and not line.startswith("#"):
        words[1], words[2] = words[2], words[1]  # a reflection: no alignment undoes it
    lines.append(" ".join(words))
with truth.open("r+") as handle:  # in place, the inode kept
    handle.write("\\n".join(lines) + "\\n")
"""

APPEND = """
import sys
from pathlib import Path
truth = Path(sys.argv[1]) / "groundtruth.txt"
Path(sys.argv[2]).write_text(truth.read_text())
with truth.open("a") as handle:
    handle.write("99.000000 5 5 5 0 0 0 1\\n")
"""

OBJECTS = """
import sys
from pathlib import Path
truth = Path(sys.argv[1]) / "groundtruth.txt"
Path(sys.argv[2]).write_text(truth.read_text())
with (Path(sys.argv[1]) / "gt" / "objects.jsonl").open("a") as handle:
    handle.write("{}\\n")
"""

FRAME_WRITER = """
import sys
from pathlib import Path
truth = Path(sys.argv[1]) / "groundtruth.txt"
Path(sys.argv[2]).write_text(truth.read_text())
first = sorted((Path(sys.argv[1]) / "rgb").iterdir())[0]
data = bytearray(first.read_bytes())
data[-20] ^= 0xFF  # same size, in place, through the linked folder
with first.open("r+b") as handle:
    handle.write(data)
"""


@pytest.fixture
def seq(tmp_path: Path) -> Path:
    write_sequence(tmp_path / "seq", n=5, with_flow=False)
    return tmp_path / "seq"


def _program(tmp_path: Path, name: str, text: str) -> str:
    script = tmp_path / f"{name}.py"
    script.write_text(text)
    return f"{shlex.quote(sys.executable)} {script} {{sequence}} {{trajectory}}"


def _honest(tmp_path: Path, seq: Path) -> str:
    """A program that answers with the true poses, kept aside before any run."""
    truth = tmp_path / "truth.txt"
    if not truth.exists():
        shutil.copyfile(seq / "groundtruth.txt", truth)
    return f"cp {truth} {{trajectory}}"


def _run(capsys, seq: Path, out: Path, command: str) -> tuple[int, str, str]:
    return cli(capsys, "run", seq, "-o", out, "--slam", "cmd", "--command", command, "--json")


@pytest.mark.parametrize(
    ("program", "name"),
    [(SWAP_XY, "groundtruth.txt"), (APPEND, "groundtruth.txt"), (OBJECTS, "gt/objects.jsonl")],
)
def test_a_program_rewriting_the_ground_truth_fails_and_later_runs_score_against_the_truth(
    seq: Path, tmp_path: Path, capsys, program: str, name: str
):
    honest = _honest(tmp_path, seq)
    before = (seq / name).read_bytes()
    code, _, err = _run(capsys, seq, tmp_path / "bad", _program(tmp_path, "vandal", program))
    assert code == 2
    one_error_line(err, f"changed {name} of the sequence it was handed")
    assert (seq / name).read_bytes() == before
    code, out, err = _run(capsys, seq, tmp_path / "good", honest)
    assert code == 0, err
    assert json.loads(out)["ate_m"]["rmse"] < 1e-6


def test_a_program_writing_a_frame_through_the_linked_folder_fails_naming_it(
    seq: Path, tmp_path: Path, capsys
):
    first = Sequence.open(seq).frames[0].rgb_path.relative_to(seq)
    code, _, err = _run(capsys, seq, tmp_path / "bad", _program(tmp_path, "frames", FRAME_WRITER))
    assert code == 2
    one_error_line(err, f"changed {seq / first}", "restore the file")


def test_the_view_holds_the_sequence_as_a_program_reads_it(seq: Path, tmp_path: Path, capsys):
    """The view reads as the sequence does: same files, same bytes, same folder name."""
    listing = tmp_path / "listing.txt"
    command = f'sh -c \'cd "$1" && pwd > {listing} && find -L . -type f | xargs sha256sum >> {listing}'
    command += ' && cp groundtruth.txt "$2"\' sh {sequence} {trajectory}'
    code, _, err = _run(capsys, seq, tmp_path / "out", command)
    assert code == 0, err
    lines = listing.read_text().splitlines()
    assert Path(lines[0]).name == seq.name
    import hashlib

    expected = sorted(
        f"{hashlib.sha256(p.read_bytes()).hexdigest()}  ./{p.relative_to(seq).as_posix()}"
        for p in seq.rglob("*")
        if p.is_file()
    )
    assert sorted(lines[1:]) == expected
