"""Freeze a benchmark: write its lock (``assets/benchmarks/NAME.lock.json``) with every
sequence's spec key and files key.

Usage: python benchmarks/freeze.py NAME [-o FOLDER] [--workers N]
       python benchmarks/freeze.py NAME --sequences FOLDER   (hash what FOLDER holds; generate nothing)

``-o`` generates every sequence into FOLDER (resumable; the machine's sequence store
serves those it holds) and hashes each. ``--sequences`` hashes the complete sequences of
FOLDER (``FOLDER/SCENARIO/NAME``, as ``benchmark run`` and ``benchmarks/calibration.py``
lay them out) whose marker holds the asked spec key and leaves the others unfrozen (no
files key): a long benchmark is frozen as its sequences are made. A files key already in
the lock is kept for a sequence whose spec key is unchanged and that FOLDER does not hold;
one FOLDER holds with other bytes stops the freeze (the same spec must give the same bytes),
unless ``--replace`` says the reference machine changed: then each key FOLDER holds other
bytes for is replaced by this machine's, and each key frozen on another machine that FOLDER
does not hold is dropped (that sequence waits to be frozen here), so that a lock never mixes
two machines' bytes (docs/benchmarks.md, "Where the keys hold"). ``--add-machine`` instead
keeps every key and adds this machine's beside those of machines of other kinds (each
sequence's ``also``), so that users of this kind of machine can score the benchmark too.
A key frozen on a machine of this one's kind (CPU and renderer) is never replaced nor
joined by another: there other bytes mean the generator changed, which needs a new
``GENERATOR_VERSION`` and a new benchmark version.

A benchmark is frozen once per version: when its sequences would change (a new generator),
its file is copied to NAME-(VERSION+1).yaml and frozen anew; the old one stays for those
who cite it.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path


def main() -> None:
    from depotbench.core.errors import InputError
    from depotbench.core.version import generator_version
    from depotbench.eval.benchmark.sequences import expand
    from depotbench.eval.benchmark.spec import (
        BenchmarkFile,
        BenchSequence,
        load_benchmark,
        lock_path,
        write_lock,
    )
    from depotbench.eval.run.detections import sequence_fingerprint
    from depotbench.scenes.generation import is_complete, run_suite
    from depotbench.scenes.schema import load_model
    from depotbench.sim.machine import machine_kind, machine_summary
    from depotbench.sim.sequence import Sequence

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("benchmark", help="a shipped benchmark's name or a benchmark file")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("-o", "--output", type=Path, help="generate every sequence here, then hash it")
    where.add_argument("--sequences", type=Path, help="hash the complete sequences this folder holds")
    parser.add_argument("--workers", type=int, default=2)
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument(
        "--replace",
        action="store_true",
        help="the reference machine changed: keys frozen on another machine give way to this one's",
    )
    mode.add_argument(
        "--add-machine",
        action="store_true",
        help="keep the keys frozen on machines of other kinds and add this machine's beside them",
    )
    args = parser.parse_args()

    from depotbench.core.examples import Kind, find

    path = find(args.benchmark, Kind.BENCHMARK)
    spec = load_model(BenchmarkFile, path)
    if spec.generator != generator_version():
        sys.exit(
            f"{path}: frozen for generator {spec.generator}, this is {generator_version()}: copy it to a new "
            "version (its name's number and version: field) and freeze that"
        )
    asked = expand(spec, path)
    kept: dict[str, BenchSequence] = {}  # the old lock's entries whose spec is still asked
    if lock_path(path).is_file():
        try:
            old = load_benchmark(path)
            specs = {(a.folder, a.spec_key) for a in asked}
            kept = {s.folder: s for s in old.sequences if (s.folder, s.spec_key) in specs}
        except InputError as exc:
            print(f"the old lock is not read ({exc}); freezing anew", flush=True)
    started = time.perf_counter()
    root = args.output or args.sequences
    if args.output is not None:
        for entry in spec.scenarios:
            run_suite(entry.suite(), path, root / entry.scenario, args.workers)
    here = machine_summary()
    kind = machine_kind(here)
    frozen, replaced, dropped, added = [], 0, 0, 0
    for sequence in asked:
        folder = root / sequence.folder
        entry = kept.get(sequence.folder, sequence)
        cleared = replace(entry, files_key=None, frozen_on=None, also=())
        complete = is_complete(folder, sequence.spec_key)
        if args.replace and entry.files_key is not None and entry.frozen_on != here and not complete:
            entry, dropped = cleared, dropped + 1
        if complete:
            hashed = sequence_fingerprint(Sequence.open(folder))
            machines = entry.machines()
            mine = [(k, m) for k, m in machines if m is not None and machine_kind(m) == kind]
            if machines and hashed not in entry.frozen_keys():
                if mine:
                    sys.exit(
                        f"{folder}: its bytes (key {hashed}) are not the ones frozen for the same spec on "
                        f"a machine of this kind ({mine[0][0]}, on {mine[0][1]}): the generator's output "
                        f"changed under generator version {generator_version()}; set GENERATOR_VERSION "
                        "(core/version.py) to the coming release and freeze a new version of the benchmark; "
                        "nothing written"
                    )
                if args.replace:
                    entry, replaced = cleared, replaced + 1
                elif args.add_machine:
                    entry, added = replace(entry, also=(*entry.also, (hashed, here))), added + 1
                else:
                    on = entry.frozen_on or "a machine the lock does not name"
                    sys.exit(
                        f"{folder}: its bytes (key {hashed}) are not the ones frozen before "
                        f"({entry.files_key}) for the same spec, on {on}; this is {here}: the generator is "
                        "not deterministic across these machines (docs/determinism.md); --add-machine adds "
                        "this machine's keys beside them; nothing written"
                    )
            elif machines and args.add_machine and not any(k == hashed for k, _ in mine):
                # the same bytes as another kind's: this kind is named beside it
                entry, added = replace(entry, also=(*entry.also, (hashed, here))), added + 1
            if entry.files_key in (None, hashed):  # frozen now, or made again here byte for byte
                entry = replace(entry, files_key=hashed, frozen_on=entry.frozen_on or here)
        frozen.append(entry)
    write_lock(path, spec, frozen)
    done = sum(s.files_key is not None for s in frozen)
    changed = f", {replaced} keys replaced and {dropped} dropped (another machine's)" if args.replace else ""
    changed += f", {added} keys of this machine added beside another's" if args.add_machine else ""
    print(
        f"wrote {lock_path(path)}: {len(frozen)} sequences, {done} frozen, {len(frozen) - done} waiting"
        f"{changed} ({time.perf_counter() - started:.0f} s)"
    )


if __name__ == "__main__":
    main()
