"""A benchmark's sequences: what its file asks the generator for, generated where missing
and checked against the lock, key by key."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.eval.benchmark.spec import Benchmark, BenchmarkFile, BenchSequence, Entry
from depotbench.scenes.schema import to_scenario
from depotbench.scenes.suite import variations
from depotbench.sim.spec import content_key

LOG = logging.getLogger(__name__)


def expand(spec: BenchmarkFile, source: Path) -> list[BenchSequence]:
    """Every sequence the file asks for, with its spec key (no files key: nothing is generated)."""
    return [sequence for entry in spec.scenarios for sequence in _entry_sequences(entry, source)]


def _entry_sequences(entry: Entry, source: Path) -> list[BenchSequence]:
    """An entry's sequences as its suite names them, each with its spec key."""
    return [
        BenchSequence(
            name, entry.scenario, knobs["seed"], scenario.n_frames, content_key(to_scenario(scenario)), None
        )
        for name, knobs, scenario in variations(entry.suite(), source)
    ]


def check_specs(benchmark: Benchmark) -> None:
    """Refuse, before anything is generated, a benchmark this package would generate other
    sequences for: another generator version, or a file edited since its lock was written."""
    from depotbench.core.version import generator_version, package_version

    asked = expand(benchmark.spec, benchmark.path)
    locked = benchmark.by_name()
    if [s.folder for s in asked] != [s.folder for s in benchmark.sequences]:
        raise InputError(
            f"{benchmark.path}: its scenarios and seeds are not its lock's; the file was edited after "
            "benchmarks/freeze.py wrote the lock"
        )
    for sequence in asked:
        if sequence.spec_key != locked[sequence.folder].spec_key:
            running = generator_version()
            why = (
                f"this depotbench ({package_version()}, generator {running}) generates other sequences "
                f"than generator {benchmark.spec.generator}, which froze it: install "
                f"depotbench=={benchmark.spec.generator} to score it"
                if running != benchmark.spec.generator
                else "its scenario changed since the benchmark was frozen"
            )
            raise InputError(f"{benchmark.name}: sequence {sequence.folder}: {why}")


@dataclass(frozen=True)
class Prepared:
    sequence: BenchSequence
    path: Path
    files_key: str


def prepare(
    benchmark: Benchmark,
    root: Path,
    workers: int,
    progress: bool = True,
    backend: str = "local",
    address: str | None = None,
) -> list[Prepared]:
    """Each sequence under ``root/SCENARIO/NAME``: generated where missing (or copied from the
    machine's sequence store), then hashed and checked against the lock. A sequence whose
    bytes are not the lock's is refused by name, so a result never mixes other bytes in."""
    from depotbench.eval.run.detections import sequence_fingerprint
    from depotbench.sim.sequence import Sequence

    check_specs(benchmark)
    for entry in benchmark.spec.scenarios:
        _generate(entry, benchmark.path, root, workers, progress, backend, address)
    prepared = []
    for sequence in benchmark.sequences:
        path = root / sequence.folder
        key = sequence_fingerprint(Sequence.open(path))
        accepted = sequence.frozen_keys()
        if accepted and key not in accepted:
            from depotbench.sim.machine import machine_summary

            machines = [on or "a machine the lock does not name" for _, on in sequence.machines()]
            frozen = "; or on ".join(machines)
            raise InputError(
                f"{path}: its files are not {benchmark.name}'s {sequence.folder} (key {key}, the lock's "
                f"{' or '.join(accepted)}): changed after generation, or made by another renderer, OpenCV "
                f"or CPU (frozen on {frozen}; this is {machine_summary()}; docs/determinism.md)"
            )
        prepared.append(Prepared(sequence, path, key))
    unfrozen = [s.folder for s in benchmark.sequences if s.files_key is None]
    if unfrozen:  # one line, however many: tum-dyn-1 is frozen as its sequences are made
        shown = ", ".join(unfrozen[:3]) + (f" and {len(unfrozen) - 3} more" if len(unfrozen) > 3 else "")
        LOG.warning(
            f"{benchmark.name}: {len(unfrozen)} of {len(benchmark.sequences)} sequences are not frozen yet "
            f"(no files key in the lock: their bytes are hashed into the results, not checked): {shown}"
        )
    return prepared


def _generate(
    entry: Entry, source: Path, root: Path, workers: int, progress: bool, backend: str, address: str | None
) -> None:
    """An entry's sequences under ``root/SCENARIO``, generated where missing (``run_suite``)."""
    from depotbench.scenes.generation import run_suite

    run_suite(
        entry.suite(), source, root / entry.scenario, workers, progress, backend=backend, address=address
    )


FRESH_SEEDS_FROM = 1_000_000
"""Fresh seeds are drawn from [10^6, 2^32): no shipped benchmark or suite uses seeds there."""


def draw_fresh_seeds(benchmark: Benchmark, count: int, entropy: int) -> dict[str, list[int]]:
    """``count`` new seeds per scenario, none of them the benchmark's, from a generator
    seeded with ``entropy`` (recorded in the results, so the draw can be made again)."""
    import numpy as np

    rng = np.random.default_rng(entropy)
    taken = {s.seed for s in benchmark.sequences}
    drawn: dict[str, list[int]] = {}
    for entry in benchmark.spec.scenarios:
        seeds: list[int] = []
        while len(seeds) < count:
            seed = int(rng.integers(FRESH_SEEDS_FROM, 2**32))
            if seed not in taken and seed not in seeds:
                seeds.append(seed)
        drawn[entry.scenario] = seeds
    return drawn


def prepare_fresh(
    benchmark: Benchmark,
    seeds: dict[str, list[int]],
    root: Path,
    workers: int,
    progress: bool = True,
    backend: str = "local",
    address: str | None = None,
) -> list[Prepared]:
    """The fresh seeds' sequences under ``root/SCENARIO``: the benchmark's scenarios at its
    lengths, generated here (no lock holds their keys; their bytes are hashed into the results)."""
    from depotbench.eval.run.detections import sequence_fingerprint
    from depotbench.sim.sequence import Sequence

    prepared = []
    for entry in benchmark.spec.scenarios:
        fresh = Entry(scenario=entry.scenario, seeds=seeds[entry.scenario], frames=entry.frames)
        _generate(fresh, benchmark.path, root, workers, progress, backend, address)
        for sequence in _entry_sequences(fresh, benchmark.path):
            path = root / sequence.folder
            prepared.append(Prepared(sequence, path, sequence_fingerprint(Sequence.open(path))))
    return prepared
