"""How a tracker parameter's value is written as text: one spelling per value, so that the
command line, sweep specs, rows and baselines compare parameters alike."""

from __future__ import annotations


def parameter_text(value: float | bool | str) -> str:
    """A value as a tracker parameter's text: integers without a point (a program's integer
    field refuses '2.0'), other numbers as ``repr`` gives them, a boolean as YAML and JSON
    spell it (``true``; ``typed`` reads it back as a boolean), text as it is."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return value
    v = float(value)
    return str(int(v)) if v.is_integer() and abs(v) < 1e15 else repr(v)
