"""Named, frozen benchmarks: which sequences a cited result was scored on, to the byte.

A benchmark file (``assets/benchmarks/NAME-VERSION.yaml``) names library scenarios, their
seeds and frame counts; its lock (``NAME-VERSION.lock.json`` beside it, written by
``benchmarks/freeze.py``) holds each sequence's two keys:

- ``spec_key``: ``depotbench.sim.spec.content_key``, what the generator is asked for (the
  scenario, seed, format and generator version). Checked before anything is generated, in
  a second: a package whose generator would make other bytes refuses the benchmark.
- ``files_key``: ``depotbench.eval.run.detections.sequence_fingerprint``, the bytes of
  every file of the sequence and its camera. Checked on every sequence a run scores: a
  sequence generated elsewhere, copied or tampered with is refused by name.

The version is part of the name (``tum-dyn-1``): a benchmark whose sequences would change
(a new generator, another seed) is a new version, and the old one stays citable with the
package version that froze it (its ``generator``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from depotbench.core.errors import InputError
from depotbench.core.examples import Kind, find
from depotbench.core.files import MAX_SPEC_BYTES, read_json
from depotbench.scenes import library
from depotbench.scenes.schema import SpecError, Strict, load_model
from depotbench.scenes.suite import Suite
from pydantic import Field, model_validator

LOCK_SUFFIX = ".lock.json"
LOCK_FORMAT = 1


class Entry(Strict):
    """One scenario of a benchmark: its seeds at one length."""

    scenario: str
    seeds: list[Annotated[int, Field(ge=0, le=2**32 - 1)]] = Field(min_length=1, max_length=1000)
    frames: int | None = Field(None, ge=2, le=100_000)
    """Frames per sequence; None keeps the scenario's own length (a TUM analog's is TUM's)."""

    @model_validator(mode="after")
    def _known(self) -> Entry:
        if self.scenario not in library.library_files():
            raise ValueError(
                f"scenario {self.scenario!r} is not in the library ({', '.join(library.names())})"
            )
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds: {self.seeds} repeats a seed")
        return self

    def suite(self) -> Suite:
        """The suite that generates this entry: named as the scenario, so that its sequences
        are the bytes ``benchmarks/calibration.py`` and a user's own suite of it make."""
        overrides = {} if self.frames is None else {"frames": self.frames}
        return Suite(suite=self.scenario, base=self.scenario, overrides=overrides, seeds=self.seeds)


class BenchmarkFile(Strict):
    benchmark: str = Field(pattern=r"^[a-z][a-z0-9-]{0,40}[a-z]$")
    version: int = Field(ge=1)
    description: str
    generator: str
    """The package version whose generator makes these sequences."""
    cite: str = ""
    scenarios: list[Entry] = Field(min_length=1)

    @model_validator(mode="after")
    def _unique(self) -> BenchmarkFile:
        names = [e.scenario for e in self.scenarios]
        if len(set(names)) != len(names):
            raise ValueError(
                f"scenarios: {names} names a scenario twice (give it all its seeds in one entry)"
            )
        return self


@dataclass(frozen=True)
class BenchSequence:
    """One sequence of a benchmark, as its lock names it."""

    name: str
    """The suite's name for it (``walking_xyz-0003``): its folder under ``sequences/SCENARIO``."""
    scenario: str
    seed: int
    frames: int
    spec_key: str
    files_key: str | None
    """None until the sequence is frozen (generated once and hashed)."""
    frozen_on: str | None = None
    """The machine and libraries that froze it (``sim.machine.machine_summary``); None in
    locks written before 0.8.0's last lock change."""

    @property
    def folder(self) -> str:
        return f"{self.scenario}/{self.name}"


@dataclass(frozen=True)
class Benchmark:
    """A benchmark file with its lock."""

    spec: BenchmarkFile
    path: Path
    sequences: tuple[BenchSequence, ...]

    @property
    def name(self) -> str:
        return f"{self.spec.benchmark}-{self.spec.version}"

    @property
    def frozen(self) -> bool:
        return all(s.files_key is not None for s in self.sequences)

    def by_name(self) -> dict[str, BenchSequence]:
        return {s.folder: s for s in self.sequences}


def lock_path(path: Path) -> Path:
    return path.with_name(path.stem + LOCK_SUFFIX)


def load_benchmark(text: str | Path) -> Benchmark:
    """A shipped benchmark by name (``tum-dyn-1``) or a benchmark file, with its lock."""
    path = find(text, Kind.BENCHMARK)
    spec = load_model(BenchmarkFile, path)
    if path.stem != f"{spec.benchmark}-{spec.version}":
        raise SpecError(
            f"{path}: a benchmark file is named NAME-VERSION.yaml ({spec.benchmark}-{spec.version}.yaml)"
        )
    lock = lock_path(path)
    if not lock.is_file():
        raise InputError(f"{lock}: the benchmark has no lock (benchmarks/freeze.py {path} writes it)")
    data = read_json(lock, MAX_SPEC_BYTES, "benchmark lock")
    try:
        if data["format"] != LOCK_FORMAT or data["benchmark"] != f"{spec.benchmark}-{spec.version}":
            raise ValueError(f"holds {data['benchmark']} (format {data['format']})")
        sequences = tuple(
            BenchSequence(
                str(s["name"]),
                str(s["scenario"]),
                int(s["seed"]),
                int(s["frames"]),
                str(s["spec_key"]),
                None if s["files_key"] is None else str(s["files_key"]),
                None if s.get("frozen_on") is None else str(s["frozen_on"]),
            )
            for s in data["sequences"]
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{lock}: not the lock of {path.name}: {exc}") from None
    return Benchmark(spec, path, sequences)


def lock_data(benchmark: BenchmarkFile, sequences: list[BenchSequence]) -> dict[str, Any]:
    return {
        "format": LOCK_FORMAT,
        "benchmark": f"{benchmark.benchmark}-{benchmark.version}",
        "generator": benchmark.generator,
        "sequences": [
            {
                "name": s.name,
                "scenario": s.scenario,
                "seed": s.seed,
                "frames": s.frames,
                "spec_key": s.spec_key,
                "files_key": s.files_key,
                **({} if s.frozen_on is None else {"frozen_on": s.frozen_on}),
            }
            for s in sequences
        ],
    }


def write_lock(path: Path, benchmark: BenchmarkFile, sequences: list[BenchSequence]) -> None:
    from depotbench.core.output import write_text_atomic

    write_text_atomic(lock_path(path), json.dumps(lock_data(benchmark, sequences), indent=1) + "\n")
