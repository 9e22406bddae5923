"""A gate file run and checked: its matrix through the sweep engine, then its budgets
(against an earlier run's rows where budgets say vs_baseline)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from depotbench.eval.gates.budgets import GateFile, GateReport
from depotbench.eval.metrics.record import RunRecord


@dataclass(frozen=True)
class Gates:
    """A gate file read and checked, with what it reads and the baseline's rows: all that
    can be refused before any folder is made or any run starts."""

    gates: GateFile
    path: Path
    inputs: tuple[Path, ...]
    """The files the matrix reads (an output folder must not be one of them)."""
    baseline: list[RunRecord] | None


def open_gates(path: Path, baseline: Path | None = None, chosen: tuple[str, ...] = ()) -> Gates:
    """The gate file at ``path`` with its matrix validated, and the rows of the earlier
    run at ``baseline`` where its budgets compare against one (they need it); ``chosen``:
    the tracker fingerprints to take from a baseline holding several program versions."""
    from depotbench.core.errors import InputError
    from depotbench.eval.gates.budgets import load_gates
    from depotbench.eval.sweep.engine import spec_inputs, validate

    gates = load_gates(path)
    if baseline is None and any(b.endswith(".vs_baseline") for c in gates.checks for b in c.budgets):
        raise InputError(f"{path}: its vs_baseline budgets need --baseline DIR (an earlier run's folder)")
    validate(gates.run, path)
    rows = load_baseline(baseline, chosen) if baseline is not None else None
    return Gates(gates, path, spec_inputs(gates.run, path), rows)


def check_folder(
    gates: Gates,
    out: Path,
    workers: int,
    backend: str = "local",
    address: str | None = None,
    retry_failed: bool = False,
) -> GateReport:
    """``run_gates`` into the folder ``out`` (resumed if it is a depotbench run folder;
    ``retry_failed``: its failed rows run again)."""
    from depotbench.core.output import OutputContainer, OutputKind

    with OutputContainer(out, OutputKind.SWEEP, inputs=gates.inputs) as container:
        return run_gates(
            gates.gates, gates.path, container.path, workers, backend, address, gates.baseline, retry_failed
        )


def run_gates(
    gates: GateFile,
    gates_path: Path,
    out: Path,
    workers: int,
    backend: str = "local",
    address: str | None = None,
    baseline: list[RunRecord] | None = None,
    retry_failed: bool = False,
) -> GateReport:
    """The gate file's matrix through the sweep engine (cache and stored rows reused), checked
    (``baseline``: an earlier run's rows, for ``vs_baseline`` budgets)."""
    from depotbench.eval.gates.budgets import evaluate
    from depotbench.eval.sweep.execute import execute_sweep

    outcome = execute_sweep(
        gates.run, gates_path, out, workers, backend=backend, address=address, retry_failed=retry_failed
    )
    return evaluate(gates, outcome.records, baseline)


def load_baseline(folder: Path, chosen: tuple[str, ...] = ()) -> list[RunRecord]:
    """An earlier check's or sweep's rows (read only), as the gates compare against them: one
    program version per tracker (a folder swept by two builds is refused, naming their
    fingerprints, unless ``chosen`` picks one; ``versions.one_version``)."""
    from depotbench.core.errors import InputError
    from depotbench.eval.metrics.versions import one_version
    from depotbench.eval.sweep.store import ResultStore

    database = folder / "results.sqlite"
    if not database.is_file():
        raise InputError(
            f"--baseline {folder}: no results.sqlite there (give an earlier check's or sweep's -o folder)"
        )
    with ResultStore(database, readonly=True) as store:
        return one_version(store.records(), chosen, folder, "--baseline-fingerprint")
