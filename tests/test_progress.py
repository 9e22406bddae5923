"""Progress off a terminal is whole lines at a steady interval, with done/total; on a
terminal it is tqdm's bar; ``-q`` and ``progress=False`` silence both (issue 39 point 4)."""

from __future__ import annotations

import fcntl
import logging
import os
import pty
import re
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest
import tqdm.std
from depotbench.core.errors import InputError
from depotbench.core.progress import INTERVAL_VARIABLE, progress_bar

from tests.sequences import write_sequence

LINE = re.compile(r"depotbench: (?P<desc>.+?) (?P<n>\d+)/(?P<total>\d+) (?P<unit>\w+)[ ,]")


@pytest.fixture(autouse=True)
def _loud(monkeypatch):
    """The ``depotbench`` logger at its default level, whatever a test before set."""
    logger = logging.getLogger("depotbench")
    monkeypatch.setattr(logger, "level", logging.NOTSET)
    monkeypatch.delenv(INTERVAL_VARIABLE, raising=False)


class Clock:
    """tqdm's clock, moved by hand."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_off_a_terminal_each_line_is_whole_and_carries_done_of_total(capsys, monkeypatch):
    monkeypatch.setenv(INTERVAL_VARIABLE, "0")
    with progress_bar(total=3, desc="decisions", unit="run") as bar:
        for _ in range(3):
            bar.update(1)
    err = capsys.readouterr().err
    assert "\r" not in err and err.endswith("\n")
    lines = err.splitlines()
    found = [LINE.match(line) for line in lines]
    assert all(found), lines
    assert [int(m["n"]) for m in found] == [0, 1, 2, 3, 3]  # opened, each step, closed
    assert {(m["desc"], m["total"], m["unit"]) for m in found} == {("decisions", "3", "run")}
    assert "(67%)" in lines[2] and "ETA" in lines[2]
    assert re.search(r", took \d\d:\d\d$", lines[-1]), lines[-1]


def test_lines_come_at_most_once_an_interval_and_none_for_shorter_work(capsys, monkeypatch):
    clock = Clock()
    monkeypatch.setattr(tqdm.std, "time", clock)
    monkeypatch.setenv(INTERVAL_VARIABLE, "10")
    bar = progress_bar(total=6, desc="sweep", unit="run")
    for at in (5.0, 11.0, 12.0, 25.0):  # seconds after the start, one run done at each
        clock.now = 1000.0 + at
        bar.update(1)
    clock.now = 1000.0 + 26.0
    bar.close()
    lines = capsys.readouterr().err.splitlines()
    # Nothing in the first 10 s; at 11 s (2 done); not at 12 s (1 s later); at 25 s (4 done).
    assert [int(LINE.match(line)["n"]) for line in lines] == [2, 4, 4]
    assert lines[-1].endswith("stopped after 00:26")  # 4 of 6 when it closed
    quick = progress_bar(total=2, desc="quick", unit="run")
    quick.update(2)
    quick.close()
    assert capsys.readouterr().err == ""  # done within the interval: nothing said


def test_a_transient_bar_says_nothing_as_it_closes(capsys, monkeypatch):
    monkeypatch.setenv(INTERVAL_VARIABLE, "0")
    for _ in progress_bar(range(2), desc="features", unit="frame", leave=False):
        pass
    assert [int(LINE.match(line)["n"]) for line in capsys.readouterr().err.splitlines()] == [0, 1, 2]


def test_quiet_and_disabled_bars_print_nothing(capsys, monkeypatch):
    monkeypatch.setenv(INTERVAL_VARIABLE, "0")
    for _ in progress_bar(range(3), desc="off", disable=True):
        pass
    logging.getLogger("depotbench").setLevel(logging.ERROR)  # what -q sets
    with progress_bar(total=3, desc="quiet") as bar:
        bar.update(3)
    assert capsys.readouterr().err == ""
    logging.getLogger("depotbench").setLevel(logging.WARNING)  # above WARNING only is quiet
    with progress_bar(total=1, desc="warning") as bar:
        bar.update(1)
    assert "warning 1/1" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["soon", "-1", "nan", "inf", "1e999"])
def test_a_bad_interval_is_refused_in_one_line_naming_the_variable(value: str, monkeypatch):
    monkeypatch.setenv(INTERVAL_VARIABLE, value)
    with pytest.raises(InputError) as caught:
        progress_bar(total=1)
    message = str(caught.value)
    assert message.startswith(f"{INTERVAL_VARIABLE}={value!r}: ") and "\n" not in message


def test_on_a_terminal_it_is_tqdms_bar_redrawn_in_place():
    """A pseudo-terminal as stderr: tqdm's bar, redrawn with carriage returns, no lines."""
    code = (
        "from depotbench.core.progress import progress_bar\n"
        "with progress_bar(total=3, desc='tty', unit='run') as bar:\n"
        "    for _ in range(3): bar.update(1)\n"
    )
    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))  # a fresh one has 0x0
    env = {**os.environ, INTERVAL_VARIABLE: "0"}
    child = subprocess.run([sys.executable, "-c", code], stderr=follower, env=env, timeout=60, check=True)
    os.close(follower)
    written = b""
    while True:
        try:
            chunk = os.read(leader, 4096)
        except OSError:  # the terminal's other end closed
            break
        if not chunk:
            break
        written += chunk
    os.close(leader)
    text = written.decode()
    assert child.returncode == 0 and "\r" in text and "tty: 100%" in text and "depotbench: " not in text


def _run_cli(tmp_path: Path, *extra: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "depotbench.eval.cli", *extra, "run", str(tmp_path / "seq"), "-o"]
        + [str(tmp_path / f"run{len(extra)}"), "--strategy", "none"],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


def test_a_run_into_a_pipe_prints_progress_lines_and_nothing_with_q(tmp_path: Path):
    write_sequence(tmp_path / "seq", n=4)
    env = {**os.environ, INTERVAL_VARIABLE: "0", "DEPOTBENCH_CACHE": "off", "MUJOCO_GL": "egl"}
    loud = _run_cli(tmp_path, env=env)
    assert loud.returncode == 0, loud.stderr
    lines = [line for line in loud.stderr.split("\n") if line.startswith("depotbench: ")]
    assert "\r" not in loud.stderr and lines, loud.stderr
    bars: dict[str, list[int]] = {}
    for line in lines:
        found = LINE.match(line)
        assert found and found["total"] == "4", line
        bars.setdefault(found["desc"], []).append(int(found["n"]))
    assert bars["slam none"] == [0, 1, 2, 3, 4]  # the tracker, frame by frame
    assert all(counts[-1] == 4 for counts in bars.values()), bars
    quiet = _run_cli(tmp_path, "-q", env=env)
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr
