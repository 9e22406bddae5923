"""A gate file run and checked: its matrix through the sweep engine, then its budgets
(against an earlier run's rows where budgets say vs_baseline)."""

from __future__ import annotations

from pathlib import Path

from depotbench.eval.gates.budgets import GateFile, GateReport


def run_gates(
    gates: GateFile,
    gates_path: Path,
    out: Path,
    workers: int,
    backend: str = "local",
    address: str | None = None,
    baseline: list[dict] | None = None,
) -> GateReport:
    """The gate file's matrix through the sweep engine (cache and stored rows reused), checked
    (``baseline``: an earlier run's rows, for ``vs_baseline`` budgets)."""
    from depotbench.eval.gates.budgets import evaluate
    from depotbench.eval.sweep.execute import execute_sweep

    outcome = execute_sweep(gates.run, gates_path, out, workers, backend=backend, address=address)
    return evaluate(gates, outcome.rows, baseline)


def load_baseline(folder: Path) -> list[dict]:
    """An earlier check's or sweep's rows (read only), as the gates compare against them."""
    from depotbench.core.errors import InputError
    from depotbench.eval.sweep.store import ResultStore

    database = folder / "results.sqlite"
    if not database.is_file():
        raise InputError(
            f"--baseline {folder}: no results.sqlite there (give an earlier check's or sweep's -o folder)"
        )
    with ResultStore(database, readonly=True) as store:
        return store.rows()
