"""Generate scenarios and suites: worker processes, resumable runs, an index of difficulty.

Jobs take plain, picklable arguments (a scenario's JSON-able data and an output
path) so they run in spawned workers now and on Ray later. A sequence folder
exists only once complete (the writer renames it into place), so a rerun skips
finished sequences and redoes the rest.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import time
import uuid
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

from tqdm import tqdm

from scenes.schema import Scenario, to_scenario
from scenes.suite import Suite, variations

INDEX_NAME = "index.json"


def _init_worker() -> None:
    # With one process per core, Mesa's llvmpipe should not spawn threads of its own.
    os.environ["LP_NUM_THREADS"] = "1"


def generate_job(scenario_data: dict[str, Any], out: str) -> dict[str, Any]:
    """Worker entry point: validate, generate, and return the sequence's difficulty."""
    from sim.generate import generate

    scenario = Scenario.model_validate(scenario_data)
    generate(to_scenario(scenario), Path(out), progress=False)
    return read_difficulty(Path(out))


def read_difficulty(sequence: Path) -> dict[str, Any]:
    meta = json.loads((sequence / "meta.json").read_text(encoding="utf-8"))
    return meta.get("difficulty", {})


def clean_partials(out_dir: Path) -> None:
    """Remove temporary folders left by a run that was killed."""
    for stale in out_dir.glob(".*.partial-*"):
        shutil.rmtree(stale, ignore_errors=True)


def write_json_atomic(path: Path, data: Any) -> None:
    tmp = path.parent / f".{path.name}.{uuid.uuid4().hex[:8]}.tmp"
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def run_suite(suite: Suite, suite_path: Path, out_dir: Path, workers: int, progress: bool = True) -> dict:
    """Generate every variation not yet complete; write ``index.json``; return the index."""
    jobs = variations(suite, suite_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    clean_partials(out_dir)
    pending = [(name, knobs, sc) for name, knobs, sc in jobs if not (out_dir / name).is_dir()]
    skipped = len(jobs) - len(pending)
    total_frames = sum(sc.n_frames for _, _, sc in pending)
    bar = tqdm(
        total=total_frames,
        unit="frame",
        desc=f"suite {suite.suite}",
        disable=not progress,
        smoothing=0.1,
    )
    bar.write(
        f"{len(jobs)} sequences: {skipped} already complete, {len(pending)} to generate "
        f"with {workers} worker(s)"
    )
    start = time.perf_counter()
    if pending:
        context = mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_init_worker) as pool:
            running: dict[Future, tuple[str, Scenario]] = {}
            queue = list(pending)
            while queue or running:
                while queue and len(running) < workers:
                    name, _, sc = queue.pop(0)
                    future = pool.submit(generate_job, sc.model_dump(mode="json"), str(out_dir / name))
                    running[future] = (name, sc)
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in done:
                    name, sc = running.pop(future)
                    future.result()  # a failed sequence stops the suite with its own error
                    bar.update(sc.n_frames)
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
                "difficulty": read_difficulty(out_dir / name),
            }
            for name, knobs, sc in jobs
        ],
    }
    write_json_atomic(out_dir / INDEX_NAME, index)
    if progress and pending:
        elapsed = time.perf_counter() - start
        print(
            f"generated {len(pending)} sequences ({total_frames} frames) in {elapsed:.1f} s "
            f"({total_frames / elapsed:.1f} frames/s); index: {out_dir / INDEX_NAME}"
        )
    return index
