"""The report's HTML, written by the Jinja2 templates in ``templates/`` from typed values.

Python decides what a page shows (which runs, which figures, what was left out and why);
the templates decide how it reads. Autoescaping is on: every text that reaches a page (a
path, a family, a tracker's label, a note) is escaped by Jinja2, none by hand. The CSS is
its own file, inlined so that the page stays one file with no network.
"""

from __future__ import annotations

import base64
import functools
import math
from dataclasses import dataclass
from importlib import resources
from typing import Any

TEMPLATES = "depotbench.eval.report.templates"


@dataclass(frozen=True)
class Table:
    """A table: its header and rows of cells (None, numbers, text or ``Mean``)."""

    header: list[str]
    rows: list[list[Any]]

    @property
    def words(self) -> list[bool]:
        """Per column, whether it holds words (in every cell that is not empty): such a column
        and its header are set flush left, where figures stay flush right. The first column
        is always flush left (the stylesheet's rule), so it is not marked."""

        def of(k: int) -> bool:
            cells = [row[k] for row in self.rows if k < len(row) and row[k] is not None]
            return k > 0 and bool(cells) and all(is_words(c) for c in cells)

        return [of(k) for k in range(len(self.header))]


@dataclass(frozen=True)
class Image:
    """A PNG or JPEG drawn for the page, inlined as a data URI."""

    data: bytes
    alt: str

    @property
    def src(self) -> str:
        kind = "jpeg" if self.data[:2] == b"\xff\xd8" else "png"
        return f"data:image/{kind};base64,{base64.b64encode(self.data).decode('ascii')}"


@dataclass(frozen=True)
class Mean:
    """A mean over runs as a table shows it: ``0.0258`` over ``[0.0229, 0.0275] n=3``."""

    shown: str
    interval: str | None
    n: int


def number(value: float, digits: int = 4) -> str:
    """Four significant digits; a figure that is not finite is a dash, as a missing one is."""
    return f"{value:.{digits}g}" if math.isfinite(value) else "–"


def is_words(value: object) -> bool:
    """Whether a table cell holds words (a strategy, a detector, a scenario) rather than a
    figure: a number, or a string that reads as one ("19/20", "-3.1 %", "12 ms")."""
    if not isinstance(value, str) or not value.strip():
        return False
    head = value.strip().lstrip("+-−–~≈<>≤≥").lstrip()
    return not (head[:1].isdigit() or head[:1] == ".")


def _template_source(name: str) -> str:
    return resources.files(TEMPLATES).joinpath(name).read_text(encoding="utf-8")


@functools.cache
def environment():
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.FunctionLoader(_template_source),
        autoescape=True,
        undefined=jinja2.StrictUndefined,  # a value the page names and Python did not give is an error
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,  # a page is a text file: it ends with a newline, as its template
    )
    env.filters["number"] = number
    env.filters["percent0"] = lambda value: f"{value:.0%}"
    env.tests["mean"] = lambda value: isinstance(value, Mean)
    return env


def render(name: str, **context: Any) -> str:
    """A whole page from ``templates/NAME`` (the stylesheet is given to every page)."""
    from markupsafe import Markup

    css = Markup(_template_source("report.css"))  # the project's own file, not user text
    return environment().get_template(name).render(css=css, **context)


def table_html(table: Table) -> str:
    """One table as a page writes it (for a caller that wants a fragment)."""
    return str(environment().get_template("macros.html.j2").module.table(table))
