"""``python -m depotbench.eval.cli``: the console script without its wrapper."""

from depotbench.eval.cli.main import entry

entry()
