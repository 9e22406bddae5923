"""Ctrl-C as a command starts: one line and exit 130, never a traceback or a leak warning.

Probe C15: a Ctrl-C 0.05-0.15 s after ``depotbench check`` started gave a 7-22-line
KeyboardInterrupt traceback and exit -2: the console script imported the package and the
command line (~0.1 s) before anything took the signal. Probe N27: a Ctrl-C while the worker
pool started left its semaphores to the resource tracker, which warned in 3 lines after the
command's own line.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tests.conftest import REPO


def _console_script() -> str:
    """What pip's wrapper for the declared console script runs (``module:function``)."""
    target = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]["depotbench"]
    module, _, function = target.partition(":")
    return f"from {module} import {function}\nsys.exit({function}())\n"


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # as from a terminal (a background run ignores it)


INTERRUPTED_WHILE_IMPORTING = """
import os, signal, sys

TARGET = sys.argv[1]

class CtrlC:
    \"\"\"Ctrl-C arrives as the import of one module starts (a keyboard's timing, made exact).\"\"\"
    def find_spec(self, name, path=None, target=None):
        if name == TARGET:
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, CtrlC())
sys.argv = ["depotbench", *sys.argv[2:]]
"""


@pytest.mark.parametrize(
    "module",
    [
        "depotbench.core.processes",  # the console script's first module, handler not yet final
        "argparse",  # the command line's own modules
        "depotbench.eval.cli.main",
        "numpy",  # an extension module, as the parser's imports load it
        "depotbench.eval.cli.gates",  # check's
    ],
)
def test_ctrl_c_while_the_console_script_loads_is_one_line(tmp_path: Path, module: str):
    """From the console script's first module on (Python's own start-up and the import of
    the package's empty __init__ files, ~3 ms, come before it): wherever the Ctrl-C lands
    in the ~0.1 s of imports, the command says so in one line and exits 130."""
    gates = REPO / "eval" / "demo_gates.yaml"
    starter = INTERRUPTED_WHILE_IMPORTING + _console_script()
    result = subprocess.run(
        [sys.executable, "-c", starter, module, "check", str(gates), "-o", str(tmp_path / "out")],
        cwd=REPO, capture_output=True, text=True, timeout=60, check=False, preexec_fn=_default_sigint,
    )  # fmt: skip
    assert result.returncode == 130 and "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and re.match(r"depotbench( check)?: interrupted", lines[0]), lines
    assert not (tmp_path / "out").exists()


LEFT_BEFORE_ITS_TRY = """
import os, sys
from depotbench.core.executors import LocalPool

if __name__ == "__main__":
    pool = LocalPool(2)  # a Ctrl-C here, before the caller's try/close, ends the command:
    sys.stderr.flush()
    os._exit(130)  # as main.entry ends an interrupted command
"""


def test_a_pool_interrupted_before_its_first_job_leaves_no_semaphores(tmp_path: Path):
    """A pool that was made but never reached its caller's ``close`` holds no semaphore the
    resource tracker would report (it reported 5 in 2 lines)."""
    script = tmp_path / "interrupted.py"
    script.write_text(LEFT_BEFORE_ITS_TRY)
    result = subprocess.run(
        [sys.executable, str(script)], cwd=REPO, capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 130
    assert result.stderr == ""


HELD_PAST_ITS_IMPORT = """
import signal, sys
from pathlib import Path

from depotbench.core import processes
from depotbench.core.output import OutputContainer, OutputKind

processes.IMPORT_POLL_S = 30.0  # the delivering thread as late as a loaded machine made it
signal.signal(signal.SIGINT, processes.OutsideImports(KeyboardInterrupt))

class CtrlC:
    def find_spec(self, name, path=None, target=None):
        if name == "colorsys":
            signal.raise_signal(signal.SIGINT)
        return None

sys.meta_path.insert(0, CtrlC())
import colorsys  # the Ctrl-C comes inside this import and is held
try:
    with OutputContainer(Path(sys.argv[1]), OutputKind.SWEEP):
        print("wrote")
except KeyboardInterrupt:
    sys.exit(130)
"""


def test_a_ctrl_c_held_in_an_import_ends_the_command_before_its_first_output(tmp_path: Path):
    """CI, one run in several: the thread that hands on a Ctrl-C held during an import polls
    every 20 ms, and on a loaded machine ``check`` made its folder in that gap. Every
    writer now delivers a held Ctrl-C before it writes, however late that thread is."""
    out = tmp_path / "out"
    result = subprocess.run(
        [sys.executable, "-c", HELD_PAST_ITS_IMPORT, str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert (result.returncode, result.stdout, result.stderr) == (130, "", "")
    assert not out.exists()
