"""``depotbench examples``: the shipped sweep specs, gate files, suites and example trackers,
listed by name, and copied into a folder to run or edit there (``examples copy``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.eval.cli.conventions import add_verbosity


def add_examples(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "examples",
        help="list the shipped sweep specs, gate files, suites and example trackers, or copy them",
    )
    p.add_argument("--json", action="store_true", help="print each example's kind, name and description")
    actions = p.add_subparsers(dest="action", metavar="ACTION", parser_class=type(p))
    c = actions.add_parser(
        "copy",
        help="copy an example (with the files it reads beside it) into a folder",
        description="Copy a shipped example into a folder, with the files it names beside it (a sweep "
        "spec's suite file, a tracker's program), so that it runs and can be edited there. An existing "
        "file is left alone and nothing is copied, unless --overwrite.",
    )
    c.add_argument("name", nargs="?", metavar="NAME", help="the example (depotbench examples lists them)")
    c.add_argument("folder", nargs="?", type=Path, metavar="DIR", help="where to copy (default: here)")
    c.add_argument("--all", action="store_true", help="copy every example: copy --all DIR")
    c.add_argument("--overwrite", action="store_true", help="replace files that exist in DIR")
    c.add_argument("--json", action="store_true", help="print the files written as a JSON list")
    add_verbosity(c, top=False)
    p.set_defaults(handler=_cmd_examples)


def _cmd_examples(args: argparse.Namespace) -> int:
    if args.action == "copy":
        return _copy(args)
    from depotbench.core.examples import examples
    from depotbench.core.files import dumps_json

    shown = list(examples().values())
    if args.json:
        print(dumps_json([e.to_dict() for e in shown]))
        return 0
    for e in shown:
        print(f"{e.kind.value:16s} {e.name:20s} {e.description}")
    print("\nrun one by name (depotbench sweep smallest -o runs/smallest), or edit a copy: "
          "depotbench examples copy NAME [DIR]")  # fmt: skip
    return 0


def _copy(args: argparse.Namespace) -> int:
    from depotbench.core.examples import copy_examples, examples
    from depotbench.core.files import dumps_json

    if args.all:
        if args.folder is not None:
            raise InputError("copy --all takes one folder: copy --all DIR")
        if args.name is None:
            raise InputError("copy --all needs the folder to copy into: copy --all DIR")
        names, folder = list(examples()), Path(args.name)
    else:
        if args.name is None:
            raise InputError("copy needs an example's name (depotbench examples lists them), or --all DIR")
        names, folder = [args.name], args.folder or Path(".")
    written = copy_examples(names, folder, overwrite=args.overwrite)
    if args.json:
        print(dumps_json([str(path) for path in written]))
    else:
        for path in written:
            print(f"wrote {path}")
    return 0
