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
