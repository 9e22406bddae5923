"""Accuracy of every rejection strategy on sequences: ATE, rho, precision, recall.

Usage: python benchmarks/strategies.py SEQUENCE [SEQUENCE ...] [-o OUT] [--set name=value ...]
Each sequence is tracked with every strategy (ground-truth boxes); results go to
OUT/<sequence>/<strategy>/ and a table (depotbench.eval.report.table) is printed.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from depotbench.eval.report.table import format_table, summarise
from depotbench.eval.run.harness import run_sequence
from depotbench.slam.config import ConfigError, parse_settings
from depotbench.slam.rejection import STRATEGIES


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("sequences", nargs="+", type=Path)
    parser.add_argument("-o", "--output", type=Path, help="keep the runs here (default: a temporary folder)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a SLAM setting")
    args = parser.parse_args()
    try:
        settings = parse_settings(args.set)
    except ConfigError as exc:
        parser.error(f"--set: {exc}")
    with tempfile.TemporaryDirectory() as tmp:
        out = args.output or Path(tmp)
        runs = {
            seq.name: {
                s: run_sequence(seq, out / seq.name / s, s, settings=settings, overwrite=True, progress=False)
                for s in STRATEGIES
            }
            for seq in args.sequences
        }
    print(format_table(summarise(runs)))


if __name__ == "__main__":
    main()
