"""Fixed-width tables for the terminal and CI logs, drawn by ``rich``.

Every command that prints a table (``eval``, a sweep's best configurations, the gates,
``compare``, ``detect-eval``'s per-class figures, ``export-rosbag``'s topics,
``benchmarks/strategies.py``) draws it here, so that columns line up however long a
family's name or a label is (a suite's family names reach 40 characters) and every table
reads alike: a header, a rule of ASCII dashes under it (a log read with another encoding
still shows it), and the rows; no colour, no wrapping. Cells are text, never rich markup:
a label with ``[k]`` in it is printed as written.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class Column:
    header: str
    align: Literal["left", "right"] = "right"


def cell(value: float | None, fmt: str) -> str:
    """A figure as a table shows it: formatted, or a dash where there is none."""
    return "-" if value is None else format(value, fmt)


def render(columns: list[Column], rows: list[list[str]], indent: int = 0) -> str:
    """The table as lines of one width (no trailing newline), each ``indent`` spaces in."""
    from rich.box import Box
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    rule_under_header = Box("    \n    \n -- \n    \n    \n    \n    \n    \n", ascii=True)
    table = Table(box=rule_under_header, show_edge=False, pad_edge=False, header_style="", expand=False)
    for column in columns:
        table.add_column(Text(column.header), justify=column.align, no_wrap=True)
    for row in rows:
        if len(row) != len(columns):
            raise ValueError(f"a row of {len(row)} cells in a table of {len(columns)} columns: {row}")
        table.add_row(*(Text(cell) for cell in row))
    out = io.StringIO()
    console = Console(file=out, width=100_000, color_system=None, highlight=False, emoji=False)
    console.print(table, crop=False)
    lines = out.getvalue().rstrip("\n").split("\n")
    width = max(len(line.rstrip()) for line in lines)
    return "\n".join(" " * indent + line.rstrip().ljust(width) for line in lines)
