"""Whether a script that starts worker processes has its ``if __name__ == "__main__":`` guard.

Workers are spawned (a fork of a process holding OpenCV's, ONNX Runtime's or an EGL
context's threads can deadlock), and a spawned worker imports the main script again before
it takes a job: a script that calls ``depotbench.sweep(..., workers=2)`` at its top level
runs its whole session once more in every worker, which dies on the session's first
side effect (``FileExistsError`` of its ``mkdir``) and leaves the parent a
``BrokenProcessPool``. Python's rule is the guard; this says so in one line, naming the
script's line, before any worker or output exists.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path
from types import FrameType, ModuleType

from depotbench.core.errors import InputError


def _reimported_file(main: ModuleType | None) -> Path | None:
    """The file a spawned worker runs again as its ``__mp_main__``, or None where it runs
    nothing (``python -c``, a notebook, ``python -m package``, an interactive session), as
    multiprocessing.spawn.get_preparation_data decides."""
    if main is None:
        return None
    spec = getattr(main, "__spec__", None)
    name = getattr(spec, "name", None)
    if name is not None and (name == "__main__" or name.endswith(".__main__")):
        return None
    text = getattr(main, "__file__", None)
    return Path(text) if text else None


def _module_frame(main: ModuleType, frame: FrameType | None) -> FrameType | None:
    """The main script's top-level frame on this stack: where its code calls into the bench."""
    found = None
    while frame is not None:
        if frame.f_globals is vars(main) and frame.f_code.co_name == "<module>":
            found = frame
        frame = frame.f_back
    return found


def _guarded_lines(source: str) -> list[tuple[int, int]]:
    """The line ranges of the script's ``if __name__ == "__main__":`` bodies."""
    ranges = []
    for node in ast.parse(source).body:
        if not isinstance(node, ast.If):
            continue
        test = node.test
        if (
            isinstance(test, ast.Compare)
            and len(test.ops) == 1
            and isinstance(test.ops[0], ast.Eq)
            and {_name(test.left), _name(test.comparators[0])} == {"__name__", "'__main__'"}
        ):
            ranges.append((node.body[0].lineno, node.body[-1].end_lineno or node.body[-1].lineno))
    return ranges


def _name(node: ast.expr) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return repr(node.value)
    return ""


def require_main_guard(option: str, workers: int) -> None:
    """Refuse to start ``workers`` > 1 processes from a script's unguarded top level: each
    worker would run the script again. Where the script cannot be read or its top level is
    not on the stack (a thread, a frozen program), nothing can be told and nothing is said."""
    if workers <= 1:
        return
    main = sys.modules.get("__main__")
    script = _reimported_file(main)
    if main is None or script is None:
        return
    frame = _module_frame(main, sys._getframe(1))
    if frame is None:
        return
    try:
        ranges = _guarded_lines(script.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, SyntaxError, ValueError):
        return
    line = frame.f_lineno
    if any(first <= line <= last for first, last in ranges):
        return
    raise InputError(
        f"{option}={workers}: {script.name}, line {line}: starting worker processes from a script's "
        'top level needs its code under `if __name__ == "__main__":` (each worker imports the '
        "script again), or workers=1"
    )
