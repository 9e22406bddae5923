"""``--vocabulary`` names what is wrong with the path: missing, a folder, or not a regular file
(``/dev/zero`` was "no such vocabulary"). ORB-SLAM3 here is the stand-in wheel
(tests/programs/stub_orbslam3), so the check runs where the real one would."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.sequences import write_sequence
from tests.test_output import cli, one_error_line
from tests.test_trackers import STUB_ORBSLAM3

CASES = [
    ("/dev/zero", "is not a regular file"),
    ("folder", "is a folder"),
    ("missing.txt", "no such vocabulary"),
]


@pytest.mark.parametrize(("name", "needle"), CASES)
def test_a_vocabulary_that_is_not_a_file_is_named_so(
    tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch, name: str, needle: str
):
    monkeypatch.syspath_prepend(str(STUB_ORBSLAM3))
    (tmp_path / "folder").mkdir()
    write_sequence(tmp_path / "seq", n=2, with_flow=False)
    vocabulary = tmp_path / name
    code, _, err = cli(capsys, "run", tmp_path / "seq", "--slam", "orbslam3", "--vocabulary", vocabulary,
                       "-o", tmp_path / "out")  # fmt: skip
    assert code != 0
    one_error_line(err)
    assert f"{vocabulary}: {needle}" in err, err


def test_orbslam3_names_a_device_as_not_a_regular_file(monkeypatch: pytest.MonkeyPatch):
    """The tracker's own check, as the API and sweeps reach it."""
    from depotbench.eval.trackers import orbslam3
    from depotbench.eval.trackers.base import TrackerError

    monkeypatch.setattr(orbslam3, "available", lambda: True)
    with pytest.raises(TrackerError, match=r"^/dev/zero: is not a regular file \(a device, pipe or socket\)"):
        orbslam3.Orbslam3Tracker(Path("/dev/zero")).run(None, progress=False)  # type: ignore[arg-type]
