"""No stored timing includes compiling the kernels (probe U1/U6).

A kernel compiles (or loads from Numba's cache) the first time a process calls it. Called
first inside a timed frame or stage, its 14 s of compiling (0.5 s of loading) landed in that
frame's time, and through the stage cache and the results store in every row that reused it:
with an empty cache a run reported 290.9 ms a frame against 78.8 warm. A fresh process here
tracks a tiny sequence through the run engine, and every dispatcher's signatures are taken as
each timed section starts and ends: none may gain one inside it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from depotbench.slam import kernels

from tests.sequences import write_sequence

REPO = Path(__file__).resolve().parents[1]

TRACKED_WHILE_WATCHED = """
import importlib, json, sys
from pathlib import Path
from numba.core.registry import CPUDispatcher
from depotbench.eval.run import stages
from depotbench.eval.run.cache import StageCache
from depotbench.eval.run.harness import RunJob, track
from depotbench.eval.trackers import builtin

def signatures():
    found = {}
    for name in ("features", "matching", "optimize", "rejection"):
        module = importlib.import_module("depotbench.slam.kernels." + name)
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.__module__ == module.__name__:
                found[name + "." + attr] = set(value.signatures)
    return found

gained = []

def watched(function):
    def timed(*args, **kwargs):
        before = signatures()
        try:
            return function(*args, **kwargs)
        finally:
            after = signatures()
            gained.extend(function.__name__ + ": " + k for k in after if after[k] - before[k])
    return timed

builtin.BuiltinTracker._run = watched(builtin.BuiltinTracker._run)  # the timed frame loop
stages._compute = watched(stages._compute)  # the timed extraction kept in the stage cache
tracked = track(RunJob(Path(sys.argv[1]), "box_epipolar_flow"), StageCache(Path(sys.argv[2])))
print(json.dumps({"gained": sorted(gained), "kernels_s": tracked.metrics["kernels_s"]}))
"""


def _track_watched(tmp_path: Path, numba_cache: Path | None) -> dict:
    sequence = tmp_path / "seq"
    write_sequence(sequence, n=4)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    if numba_cache is not None:
        env["NUMBA_CACHE_DIR"] = str(numba_cache)
    result = subprocess.run(
        [sys.executable, "-c", TRACKED_WHILE_WATCHED, str(sequence), str(tmp_path / "stages")],
        capture_output=True, text=True, timeout=300, check=False, cwd=REPO, env=env,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


pytestmark = pytest.mark.skipif(not kernels.compiled(), reason="the NumPy path compiles nothing")


def test_no_kernel_loads_inside_a_timed_frame_or_stage(tmp_path: Path):
    """With the cache tests/prepare.py fills, loading (0.5 s) still happens at a kernel's first
    call: it must happen before the clock starts, and its seconds be kept apart."""
    found = _track_watched(tmp_path, None)
    assert found["gained"] == []
    assert found["kernels_s"] > 0


@pytest.mark.slow
def test_no_kernel_compiles_inside_a_timed_frame_from_an_empty_cache(tmp_path: Path):
    """The first run after an install: every kernel compiles (14 s on 2 busy cores), all of
    it before the first timed frame, and the run says how long it took."""
    found = _track_watched(tmp_path, tmp_path / "numba")
    assert found["gained"] == []
    assert found["kernels_s"] > 1.0  # compiled here, not loaded
    assert any((tmp_path / "numba").rglob("*.nbi"))  # and kept for the next run


def _timed_rows(version: int) -> list:
    """A none run and a box_rule run of one sequence, 20 and 30 ms a frame, of ``version``."""
    from tests.records import record

    return [
        record(key=f"{strategy}", strategy=strategy, track_ms_mean=ms, record_version=version)
        for strategy, ms in (("none", 20.0), ("box_rule", 30.0))
    ]


@pytest.mark.parametrize("version", [6, 7])
def test_rows_timed_before_compiling_was_kept_apart_are_marked(version: int):
    """Rows already stored may hold compile time and are not re-measured in place: a gate on
    their time and a sweep summary say so; a row of record version 7 or later is not marked."""
    import yaml
    from depotbench.eval.gates.budgets import GateFile, evaluate
    from depotbench.eval.sweep.summary import configurations

    budgets = "{time_ratio: {max: 2.0}, track_ms_mean.mean: {max: 50}}"
    checks = f"- name: speed\n  strategies: [box_rule]\n  budgets: {budgets}"
    gates = GateFile.model_validate(yaml.safe_load(f"gates: g\nrun: {{sequences: [x]}}\nchecks:\n{checks}"))
    report = evaluate(gates, _timed_rows(version))
    notes = [v.note for result in report.results for v in result.verdicts]
    marked = [note for note in notes if "timing may include compilation" in note]
    assert len(marked) == (2 if version < 7 else 0), notes
    summary = configurations(_timed_rows(version))
    expected = "timing may include compilation" if version < 7 else None
    assert [c.get("timing") for c in summary] == [expected] * 2
