"""The terminal tables (``core/text_table.py``, drawn by rich): columns line up whatever the
cells hold, numbers are right-aligned on one edge, and a cell is printed as written."""

from __future__ import annotations

import pytest
from depotbench.core.text_table import Column, render


def test_columns_line_up_and_numbers_share_their_right_edge():
    rows = [["walkers actors.0.count=12 camera.motion=xyz", "0.0123", "-"], ["b", "12.5", "55.1"]]
    lines = render([Column("family", "left"), Column("ATE m"), Column("rho %")], rows).splitlines()
    header, rule, *body = lines
    assert len({len(line) for line in lines}) == 1
    assert set(rule.strip()) == {"-"}
    assert [line.index(cell) for line, cell in zip(body, ("0.0123", "12.5"), strict=True)] == [
        header.index("ATE m") + len("ATE m") - len(cell) for cell in ("0.0123", "12.5")
    ]
    assert all(line.rstrip().endswith(cell) for line, cell in zip(body, ("-", "55.1"), strict=True))
    assert body[1].startswith("b ")


def test_a_cell_is_printed_as_written_never_as_markup():
    text = render([Column("label", "left")], [["box_rule [k] [bold]x[/bold] :smile:"]])
    assert text.splitlines()[-1].strip() == "box_rule [k] [bold]x[/bold] :smile:"


def test_an_indented_table_and_a_row_of_the_wrong_length():
    assert all(line.startswith("  ") for line in render([Column("a")], [["1"]], indent=2).splitlines())
    with pytest.raises(ValueError, match="a row of 2 cells in a table of 1 columns"):
        render([Column("a")], [["1", "2"]])
