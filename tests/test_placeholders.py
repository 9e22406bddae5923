"""``run --help`` names every placeholder of the external-program protocol: the help is built
from the tuple the command tracker fills in, and the documentation's table and the template
parser agree with it (the help listed 5 of the 9)."""

from __future__ import annotations

import re

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.cli.main import build_parser
from depotbench.eval.trackers.command import parse_template
from depotbench.eval.trackers.placeholders import PLACEHOLDERS

from tests.conftest import REPO

BRACED = re.compile(r"\{([A-Za-z_]+)\}")


def _command_help() -> str:
    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "verb").choices
    (action,) = [a for a in commands["run"]._actions if "--command" in a.option_strings]
    return action.help


def test_run_help_lists_every_placeholder_in_order():
    named = BRACED.findall(_command_help())
    assert named == [*PLACEHOLDERS, "NAME"]  # NAME: each --param's own placeholder
    # ...and the page argparse wraps shows each of them whole
    text = next(a for a in build_parser()._actions if a.dest == "verb").choices["run"].format_help()
    assert all(f"{{{name}}}" in text for name in PLACEHOLDERS)


def test_the_documented_table_holds_the_same_placeholders():
    page = (REPO / "docs" / "external-trackers.md").read_text()
    rows = re.findall(r"^\| `\{([A-Za-z_]+)\}` \|", page, flags=re.MULTILINE)
    assert sorted(rows) == sorted([*PLACEHOLDERS, "NAME"])


def test_the_template_parser_takes_what_the_help_lists_and_refuses_the_rest():
    named = [name for name in BRACED.findall(_command_help()) if name != "NAME"]
    words = parse_template("./slam " + " ".join(f"{{{name}}}" for name in named))
    assert len(words) == len(PLACEHOLDERS) + 1
    with pytest.raises(InputError) as refused:
        parse_template("./slam {depth}")
    known = re.findall(r"\{([A-Za-z_]+)\}", str(refused.value).split("known:", 1)[1])
    assert known == named
