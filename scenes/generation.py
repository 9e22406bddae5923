"""Generate suites: worker processes, resumable by content, an index of difficulty.

Jobs take plain, picklable arguments (a scenario's JSON-able data and an output
path) so they run in spawned workers now and on Ray later. A sequence counts as
complete only when its marker holds the content key of what is asked for now
(spec, seed, format and generator version); anything else is regenerated. The
suite folder is locked while a run owns it, each sequence while a worker writes
it, and workers die with their parent. A sequence the shared store holds
(``depotbench.scenes.store``) is copied from it instead of rendered, and every sequence rendered
is added to it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from depotbench.core.executors import make_pool
from depotbench.core.files import DEFAULT_PNG_COMPRESSION, MAX_META_BYTES, MIB, dumps_json, read_json
from depotbench.core.output import (
    OutputContainer,
    OutputKind,
    check_replaceable,
    clean_if_unowned,
    read_marker,
    write_text_atomic,
)
from depotbench.core.progress import progress_bar
from depotbench.scenes.schema import Scenario, to_scenario
from depotbench.scenes.shipping import render_on_node, unpack_output
from depotbench.scenes.store import SequenceStore
from depotbench.scenes.suite import Suite, variations
from depotbench.sim.sensor_profiles import profile_name
from depotbench.sim.spec import SensorSpec, content_key

LOG = logging.getLogger(__name__)

INDEX_NAME = "index.json"
INDEX_MAX_BYTES = 16 * MIB
"""A suite folder's index: the suite limit's 10,000 sequences take about 3 MB."""


def generate_job(scenario_data: dict[str, Any], out: str, png_compression: int) -> dict[str, Any]:
    """Worker entry point: validate, generate (replacing a stale sequence), return its difficulty."""
    from depotbench.sim.generate import generate

    scenario = Scenario.model_validate(scenario_data)
    generate(
        to_scenario(scenario), Path(out), progress=False, overwrite=True, png_compression=png_compression
    )
    return read_difficulty(Path(out))


def read_difficulty(sequence: Path) -> dict[str, Any]:
    meta = read_json(sequence / "meta.json", MAX_META_BYTES, "sequence's meta.json")
    return meta.get("difficulty", {}) if isinstance(meta, dict) else {}


def is_complete(sequence: Path, key: str) -> bool:
    """True when ``sequence`` is a complete depotbench sequence holding exactly ``key``."""
    marker = read_marker(sequence)
    return marker is not None and marker.kind is OutputKind.SEQUENCE and marker.content_key == key


def _generate_all(
    pending: list[tuple[str, Scenario]],
    out_dir: Path,
    workers: int,
    bar: Any,  # depotbench.core.progress.progress_bar's
    backend: str = "local",
    address: str | None = None,
    png_compression: int = DEFAULT_PNG_COMPRESSION,
    done: Callable[[str], None] | None = None,
) -> None:
    """Render ``pending`` into ``out_dir``; ``done(name)`` is called in this process as
    each sequence is complete."""
    # Always in worker processes (even one): rendering stays out of the caller's process.
    pool = make_pool(backend, workers, address, in_process=False)
    failed = True
    try:
        # On a cluster a node renders and sends the sequence back: only this process writes here.
        where = (lambda name: name) if pool.ships else (lambda name: str(out_dir / name))
        items = [(sc.model_dump(mode="json"), where(name), png_compression) for name, sc in pending]
        results = pool.map_unordered(render_on_node if pool.ships else generate_job, items)
        scenarios = dict(pending)
        for (_, out, _), packed in results:  # a failure raises its own error
            name = Path(out).name
            if pool.ships:
                key = content_key(to_scenario(scenarios[name]))
                unpack_output(packed, out_dir / name, OutputKind.SEQUENCE, key)
            if done is not None:
                done(name)
            bar.update(scenarios[name].n_frames)
        failed = False
    finally:
        pool.close(failed)
        if failed:  # the killed workers' staging folders and locks: nothing half-written stays
            for name, _ in pending:
                clean_if_unowned(out_dir / name)


def run_suite(
    suite: Suite,
    suite_path: Path,
    out_dir: Path,
    workers: int,
    progress: bool = True,
    overwrite: bool = False,
    backend: str = "local",
    address: str | None = None,
    png_compression: int = DEFAULT_PNG_COMPRESSION,
    store: SequenceStore | None | bool = True,
) -> dict:
    """Generate every variation whose sequence is missing or stale; write ``index.json``.

    ``backend`` ``ray`` generates on a Ray cluster (``depotbench.core.executors``); the bytes are the same.

    ``overwrite`` regenerates every sequence, even those that are up to date.
    ``png_compression`` is the zlib level of the PNGs (0: fastest, largest).
    ``store``: the shared sequence store (``depotbench.scenes.store``) to copy held sequences from
    instead of rendering them, and to add rendered ones to; True (the default) takes the
    one the environment names, None or False none. ``overwrite`` renders every sequence.
    """
    if store is True:  # locally, spawned workers render: they load numpy as the bench sets it
        store = SequenceStore.from_env(workers=backend == "local")
    store = store or None

    def has(key: str) -> bool:
        return store is not None and store.has(key, png_compression)

    def fetch(key: str, target: Path) -> bool:
        return store is not None and store.fetch(key, target, png_compression)

    jobs = variations(suite, suite_path)
    with OutputContainer(out_dir, OutputKind.SUITE, inputs=(suite_path,)) as container:
        root = container.path
        keys = {name: content_key(to_scenario(sc)) for name, _, sc in jobs}
        for name, _, _ in jobs:  # never replace a folder depotbench did not write
            clean_if_unowned(root / name)
            check_replaceable(root / name, out_dir / name, OutputKind.SEQUENCE, overwrite=True)
        missing = [
            (name, sc) for name, _, sc in jobs if overwrite or not is_complete(root / name, keys[name])
        ]
        stale = sum((root / name).exists() for name, _ in missing)
        held = [] if overwrite else [(n, sc) for n, sc in missing if has(keys[n])]
        LOG.info(  # before the copies: a suite of many held sequences takes seconds to copy
            f"{len(jobs)} sequences: {len(jobs) - len(missing)} complete, {len(held)} from the store and "
            f"{len(missing) - len(held)} to generate ({stale} of those stale or replaced) "
            f"with {workers} worker(s)"
        )
        started = time.perf_counter()
        copied = [name for name, _ in held if fetch(keys[name], root / name)]
        copy_s = time.perf_counter() - started
        pending = [(name, sc) for name, sc in missing if name not in copied]
        total_frames = sum(sc.n_frames for _, sc in pending)
        bar = progress_bar(
            total=total_frames,
            unit="frame",
            desc=f"suite {suite.suite}",
            disable=not progress,
            smoothing=0.1,
        )
        if len(copied) < len(held):  # evicted between the count and the copy
            bar.write(f"{len(held) - len(copied)} left the store meanwhile (evicted): generating them")

        def stored(name: str) -> None:
            if store is not None:
                store.put(root / name, keys[name], png_compression)

        start = time.perf_counter()
        try:
            if pending:
                _generate_all(pending, root, workers, bar, backend, address, png_compression, stored)
        finally:
            bar.close()
        index = {
            "suite": suite.suite,
            "description": suite.description,
            "sequences": [
                {
                    "name": name,
                    "knobs": knobs,
                    "seed": sc.seed,
                    "frames": sc.n_frames,
                    "sensor_profile": profile_name(SensorSpec(**sc.sensor.model_dump())),
                    "content_key": keys[name],
                    "difficulty": read_difficulty(root / name),
                }
                for name, knobs, sc in jobs
            ],
        }
        write_text_atomic(root / INDEX_NAME, dumps_json(index) + "\n")
    if progress and (pending or copied):
        elapsed = time.perf_counter() - start
        parts = []
        if pending:
            parts.append(
                f"generated {len(pending)} sequences ({total_frames} frames) in {elapsed:.1f} s "
                f"({total_frames / elapsed:.1f} frames/s)"
            )
        if copied:
            parts.append(f"copied {len(copied)} from the store in {copy_s:.1f} s")
        LOG.info(f"{'; '.join(parts)}; index: {out_dir / INDEX_NAME}")
    return index
