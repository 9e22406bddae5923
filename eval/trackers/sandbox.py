"""Settings templates compiled and rendered where they reach nothing: Jinja2's immutable
sandbox, in a child process with bounded memory, processor time, wall time and output.

The sandbox refuses attributes such as ``__globals__`` (``cycler.__init__.__globals__.os``
ran any command inside the bench, under ``validate`` too) and its loader holds no file
(``include``, ``import`` and ``extends`` name nothing). What a sandbox cannot bound on its
own is bounded here: ``*`` and ``**`` refuse a result past the output cap before building
it (``'x' * 4000000000``), ``range`` stops at Jinja2's ``MAX_RANGE`` (100,000 items), the
output is cut at ``limit`` bytes, and the child may use ``MEMORY_BYTES`` of address space
and ``RENDER_S`` seconds, so that any other bomb (``~`` doubling a string, a format width,
a loop with no output) ends as one line instead of taking the bench's memory or time.
Whatever goes wrong in the child, ``RecursionError`` and ``MemoryError`` included, comes
back as one line.

Run as a script (``python -I -S sandbox.py``), it is the child: it reads one JSON request
on its standard input and imports nothing but the standard library and Jinja2.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

RENDER_S = 0.5
"""A settings template renders in milliseconds; one still running after this many seconds is
refused (processor time is cut at the next whole second and one more), so that a hostile
template is answered within a second, the child's start included (0.2-0.3 s)."""
STARTUP_S = 20.0
"""The child's start (Python and Jinja2, 0.3 s on a loaded machine) on top of ``RENDER_S``."""
MEMORY_BYTES = 256 << 20
"""The child's address space: Python with Jinja2 needs under 64 MiB."""
REASON_CHARS = 300
"""A refusal's reason is cut to this many characters (one line)."""


class TemplateRefused(Exception):
    """The template cannot be compiled or rendered: ``line`` (1-based, when known) and one
    line of ``reason``."""

    def __init__(self, reason: str, line: int | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.line = line


RENDERED_KEPT = 256
"""Renderings kept per process: a sweep renders one template for every job, mostly with
the same camera and parameters, and a child costs 0.1-0.8 s where the program may take 1 s."""
_rendered: dict[str, str] = {}


def render(text: str, variables: dict | None, limit: int) -> str:
    """``text`` rendered with ``variables`` (JSON values) in the sandboxed child, or only
    compiled when ``variables`` is None (then ""). Raises ``TemplateRefused``. A rendering
    is a function of its request, so one already made in this process is returned again."""
    memo = json.dumps([text, variables, limit], sort_keys=True)
    if memo in _rendered:
        return _rendered[memo]
    out = _render(text, variables, limit)
    if len(_rendered) >= RENDERED_KEPT:
        _rendered.pop(next(iter(_rendered)))
    _rendered[memo] = out
    return out


def _render(text: str, variables: dict | None, limit: int) -> str:
    request = {
        "path": [p for p in sys.path if p],
        "text": text,
        "variables": variables,
        "limit": limit,
        "seconds": RENDER_S,
    }
    child = subprocess.Popen(
        [sys.executable, "-I", "-S", str(Path(__file__).resolve())],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,  # a signal to the bench's group reaches it through us
    )
    try:
        out, err = child.communicate(json.dumps(request).encode("utf-8"), timeout=RENDER_S + STARTUP_S)
    except subprocess.TimeoutExpired:
        child.kill()
        child.communicate()
        raise TemplateRefused(f"it ran past the limit of {RENDER_S:g} s") from None
    except BaseException:
        child.kill()
        child.wait()
        raise
    if child.returncode == 0:
        return out.decode("utf-8")
    lines = [line for line in err.decode("utf-8", "replace").splitlines() if line.strip()]
    if child.returncode == 3 and lines:  # the child's own one-line answer
        answer = json.loads(lines[-1])
        raise TemplateRefused(answer["reason"], answer["line"])
    if child.returncode == -signal.SIGXCPU:
        raise TemplateRefused(f"it ran past the limit of {RENDER_S:g} s of processor time")
    how = (
        f"was killed by signal {-child.returncode}"
        if child.returncode < 0
        else f"exited with code {child.returncode}"
    )
    last = lines[-1][:REASON_CHARS] if lines else "no message"
    raise TemplateRefused(f"its renderer {how} ({last})")


# -- the child ------------------------------------------------------------------------------------


def _environment(limit: int, deadline: float):
    """Jinja2's immutable sandbox with StrictUndefined, no loader's files, no constant
    folding (it would run ``'x' * 4000000000`` while compiling) and bounded ``*``/``**``."""
    import jinja2
    from jinja2.sandbox import ImmutableSandboxedEnvironment, SecurityError

    class NoFiles(jinja2.BaseLoader):
        def get_source(self, environment, template):
            raise jinja2.TemplateNotFound(
                template,
                f"{template!r}: a settings template is one file; it includes, imports and extends nothing",
            )

    def check_time() -> None:
        if time.monotonic() > deadline:
            raise SecurityError(f"it ran past the limit of {RENDER_S:g} s")

    class Sandbox(ImmutableSandboxedEnvironment):
        intercepted_binops = frozenset({"*", "**"})

        def call_binop(self, context, operator, left, right):
            check_time()
            too_big = _too_big(operator, left, right, limit)
            if too_big:
                raise SecurityError(too_big)
            return super().call_binop(context, operator, left, right)

        def call(__self, __context, __obj, *args, **kwargs):  # noqa: N805 (Jinja2's signature)
            check_time()
            return super().call(__context, __obj, *args, **kwargs)

        def getattr(self, obj, attribute):
            check_time()
            return super().getattr(obj, attribute)

    return Sandbox(
        loader=NoFiles(),
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
        autoescape=False,
        optimized=False,
    )


def _too_big(operator: str, left: object, right: object, limit: int) -> str | None:
    """Why ``left operator right`` would pass ``limit`` bytes, before it is built."""
    if operator == "*":
        for items, times in ((left, right), (right, left)):
            sized = isinstance(items, (str, bytes, list, tuple)) and isinstance(times, int)
            if sized and len(items) * times > limit:
                return f"a repetition of {len(items)} x {times} items passes the limit of {limit} bytes"
    powers = operator == "**" and isinstance(left, int) and isinstance(right, int)
    if powers and abs(left) > 1 and right > 0 and right * math.log2(abs(left)) > 8 * limit:
        return f"{left} ** {right} has more digits than the limit of {limit} bytes"
    return None


def _child(request: dict) -> str:
    limit, seconds = int(request["limit"]), float(request["seconds"])
    deadline = time.monotonic() + seconds
    environment = _environment(limit, deadline)
    template = environment.from_string(request["text"])
    if request["variables"] is None:
        return ""
    parts, size = [], 0
    for part in template.generate(**request["variables"]):
        size += len(part.encode("utf-8"))
        if size > limit:
            raise TemplateRefused(f"its output passes the limit of {limit} bytes")
        if time.monotonic() > deadline:
            raise TemplateRefused(f"it ran past the limit of {seconds:g} s")
        parts.append(part)
    return "".join(parts)


def _reason(exc: BaseException) -> tuple[str, int | None]:
    """One line for anything a template raised, and its line where Jinja2 knows it."""
    if isinstance(exc, TemplateRefused):
        return exc.reason, exc.line
    if isinstance(exc, MemoryError):
        return f"it needs more than the {MEMORY_BYTES >> 20} MiB a template may use", None
    if isinstance(exc, RecursionError):
        return "it recurses without end (a macro that calls itself?)", None
    message = getattr(exc, "message", None) or str(exc)
    text = " ".join(str(message).split()) or type(exc).__name__
    kind = type(exc).__name__
    return (text if kind in text else f"{kind}: {text}")[:REASON_CHARS], getattr(exc, "lineno", None)


def main() -> int:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_BYTES, MEMORY_BYTES))
    cpu = math.ceil(RENDER_S) + 1
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))
    try:
        request = json.loads(sys.stdin.buffer.read())
        sys.path[:0] = request["path"]
        out = _child(request)
    except BaseException as exc:  # noqa: BLE001 (every failure of a template is one line)
        try:
            reason, line = _reason(exc)
        except BaseException:  # noqa: BLE001 (MemoryError while describing one)
            reason, line = type(exc).__name__, None
        os.write(2, (json.dumps({"reason": reason, "line": line}) + "\n").encode("utf-8"))
        return 3
    sys.stdout.buffer.write(out.encode("utf-8"))
    sys.stdout.buffer.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
