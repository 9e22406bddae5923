"""``depotbench validate``: any of the bench's YAML files checked before a long run, its
kind read from the file (the one top-level key each kind must have), each problem on a
line of its own naming the file and the field.

A kind is an entry in ``KINDS``: the key that marks it and the check that loads it the
way the command that runs it does (a sweep spec also opens the sequences it names).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError


@dataclass(frozen=True)
class Checked:
    """One file's verdict: its kind, a one-line summary when it is valid, else its problems."""

    name: str
    kind: str
    summary: str = ""
    problems: tuple[str, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_dict(self) -> dict[str, Any]:
        return {
            "file": self.name,
            "kind": self.kind,
            "ok": self.ok,
            "summary": self.summary,
            "problems": list(self.problems),
        }


def _scenario(path: Path | str) -> str:
    from depotbench.scenes.resolve import scenario_model

    scenario = scenario_model(path)
    return (
        f"'{scenario.name}', {scenario.n_frames} frames, {sum(a.count for a in scenario.actors)} actors, "
        f"camera {scenario.camera.motion}"
    )


def _suite(path: Path) -> str:
    from depotbench.scenes.suite import load_suite, variations

    jobs = variations(load_suite(path), path)
    return f"{len(jobs)} sequences, {sum(sc.n_frames for _, _, sc in jobs)} frames in all"


def _sweep(path: Path) -> str:
    from depotbench.eval.sweep.engine import validate
    from depotbench.eval.sweep.spec import load_sweep

    spec = load_sweep(path)
    validate(spec, path)  # trackers, detectors, thresholds, and the sequences it names, opened
    source = f"suite {spec.suite}" if spec.suite else f"{len(spec.sequences)} sequence entries"
    return f"'{spec.sweep}', {len(spec.strategies)} strategies over {source}"


def _gates(path: Path) -> str:
    from depotbench.eval.gates.budgets import load_gates
    from depotbench.eval.sweep.engine import validate

    gates = load_gates(path)
    validate(gates.run, path)
    budgets = sum(len(c.budgets) for c in gates.checks)
    return f"'{gates.gates}', {len(gates.checks)} checks, {budgets} budgets"


@dataclass(frozen=True)
class Kind:
    key: str
    """The top-level key that marks a file of this kind (``None``: the fallback)."""
    check: Callable[[Path], str]


KINDS: dict[str, Kind] = {
    "gate file": Kind("gates", _gates),
    "sweep spec": Kind("sweep", _sweep),
    "suite": Kind("suite", _suite),
}
SCENARIO = "scenario"
"""A file with none of the keys above, or a library scenario's name."""


def kind_of(path: Path) -> str:
    from depotbench.scenes.schema import read_yaml

    data = read_yaml(path)
    return next((name for name, kind in KINDS.items() if kind.key in data), SCENARIO)


def validate_file(name: str) -> Checked:
    """``name`` (a file, a shipped example's name or a library scenario's name) checked; a
    user's mistake becomes its problems, one per line of the message (pydantic's errors are
    one per field)."""
    from depotbench.core.examples import Kind, examples

    path = Path(name)
    shipped = examples().get(name)
    if not path.exists() and shipped is not None and shipped.kind is not Kind.TRACKER:
        path = shipped.path  # a shipped spec by name; a path that exists wins
    kind = SCENARIO
    try:
        if path.is_file():
            kind = kind_of(path)
        if kind == SCENARIO:
            return Checked(name, kind, _scenario(path if path.is_file() else name))
        return Checked(name, kind, KINDS[kind].check(path))
    except InputError as exc:
        return Checked(name, kind, problems=tuple(line for line in str(exc).splitlines() if line.strip()))
