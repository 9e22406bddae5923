"""``python -m depotbench.eval.cli``: the console script without its wrapper."""

from depotbench.eval.cli.console import entry

entry()
