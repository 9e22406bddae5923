"""SIGKILL at random moments never leaves a half-written output or a live orphan.

Two writers are killed over and over, each at a moment drawn from a seeded
generator over its measured lifetime (half of the draws in its last third, where
results are written and swapped in):

- ``depotbench run --overwrite``, alternating two strategies, so that each run
  replaces the other's complete output: after every kill the output folder must
  be exactly one of the two complete outputs.
- suite generation, alternating two versions of a suite whose sequences differ:
  after every kill of the parent (only the parent: its workers must notice and
  stop by themselves) each sequence folder must be exactly one of its two
  complete versions, and no worker may live on.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from depotbench.core.output import read_marker

from tests.conftest import REPO
from tests.test_output import snapshot, wait_until_gone

pytestmark = pytest.mark.render

KILLS = int(os.environ.get("DEPOTBENCH_KILLS", "20"))
"""Kills per target (the reliability issue asks for at least 20): the slow suite's count."""
QUICK_KILLS = 4
"""The default run's count for ``run --overwrite``: 2 per strategy, one anywhere in the run and
one after it (the output swapped); the slow suite's 20 put half of them late."""


def start(args: list[str], token: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "depotbench.eval.cli", *args],
        cwd=REPO,
        env={**os.environ, "DEPOTBENCH_TEST_TOKEN": token, "MUJOCO_GL": "egl"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(args: list[str], token: str) -> float:
    """Run to completion; return the wall time."""
    began = time.perf_counter()
    proc = start(args, token)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    return time.perf_counter() - began


def kill_moments(rng: np.random.Generator, lifetime_s: float, n: int, past: int = 0) -> np.ndarray:
    """Half spread over the whole lifetime, half in its last third (writing and swapping).

    ``past`` of the late moments fall well after the measured lifetime, so that
    some runs surely finish even when this one is slower than the measured one
    (a two-core CI machine varies by a fifth from run to run).
    """
    spread = rng.uniform(0.0, 1.05 * lifetime_s, n - n // 2)
    late = rng.uniform(0.66 * lifetime_s, 1.05 * lifetime_s, n // 2 - past)
    after = rng.uniform(1.3 * lifetime_s, 1.6 * lifetime_s, past)
    return rng.permutation(np.concatenate([spread, late, after]))


def kill_at(args: list[str], token: str, delay_s: float) -> None:
    proc = start(args, token)
    try:
        proc.wait(timeout=delay_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".") and p.name != ".depotbench.json")


@pytest.fixture(scope="module")
def smoke_sequence(tmp_path_factory) -> Path:
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate

    out = tmp_path_factory.mktemp("kill") / "smoke"
    return generate(to_scenario(library.get("smoke")), out, progress=False)


@pytest.mark.parametrize("kills", [QUICK_KILLS, pytest.param(KILLS, marks=pytest.mark.slow)])
def test_run_overwrite_killed_at_random_moments(smoke_sequence: Path, tmp_path: Path, kills: int):
    token = f"kill-run-{os.getpid()}-{time.time_ns()}"
    out = tmp_path / "out"

    def args(strategy: str, target: Path) -> list[str]:
        return ["run", str(smoke_sequence), "-o", str(target), "--strategy", strategy, "--overwrite"]

    strategies = ("box_rule", "none")
    # each strategy's lifetime, measured on its own (they differ): the slower of two runs
    lifetime = {s: max(finish(args(s, tmp_path / f"ref-{s}"), token) for _ in range(2)) for s in strategies}
    complete = {s: (tmp_path / f"ref-{s}" / "trajectory.txt").read_bytes() for s in strategies}
    finish(args("none", out), token)
    seen = {"none": 0, "box_rule": 0}
    rng = np.random.default_rng(20261123)
    moments = {s: kill_moments(rng, lifetime[s], kills // 2, past=1) for s in strategies}
    schedule = [(s, moments[s][i]) for i in range(kills // 2) for s in strategies]
    for k, (strategy, delay) in enumerate(schedule):
        kill_at(args(strategy, out), token, float(delay))
        files = snapshot(out)  # the output is there, complete, and one of the two
        holds = [s for s, trajectory in complete.items() if files.get("trajectory.txt") == trajectory]
        assert len(holds) == 1, f"kill {k} after {delay:.2f} s left {sorted(files)}"
        assert {"metrics.json", "diagnostics.npz", ".depotbench.json"} <= files.keys()
        assert read_marker(out) is not None
        seen[holds[0]] += 1
    assert wait_until_gone(token) == []
    print(f"{kills} kills of run --overwrite; the output held afterwards: {seen}")
    assert min(seen.values()) > 0, seen  # kills fell both before and after the swap
    finish(args("none", out), token)
    assert leftovers(tmp_path) == []


SUITE = """suite: k
base: smoke
overrides: {{frames: 5, image: {{width: 96, height: 72}}, intrinsics: {{fx: 78.75}}}}
grid:
  actors.0.speed_mps: [{speed}]
seeds: [1, 2, 3]
"""


@pytest.mark.slow  # 90 s; the run kill test and the suite resume test stay in the default run
def test_suite_generation_killed_at_random_moments(tmp_path: Path):
    token = f"kill-suite-{os.getpid()}-{time.time_ns()}"
    versions = {}
    for speed in ("0.6", "1.4"):
        spec = tmp_path / f"suite-{speed}.yaml"
        spec.write_text(SUITE.format(speed=speed))
        versions[speed] = spec
    lifetime = finish(["generate", str(versions["0.6"]), "-o", str(tmp_path / "ref-0.6")], token)
    finish(["generate", str(versions["1.4"]), "-o", str(tmp_path / "ref-1.4")], token)
    names = ["k-0000", "k-0001", "k-0002"]
    reference = {speed: {n: snapshot(tmp_path / f"ref-{speed}" / n) for n in names} for speed in versions}
    assert reference["0.6"]["k-0000"] != reference["1.4"]["k-0000"]
    out = tmp_path / "out"
    held = dict.fromkeys(names, 0)
    staged = 0
    rng = np.random.default_rng(11)
    for k, delay in enumerate(kill_moments(rng, lifetime, KILLS)):
        spec = versions[("1.4", "0.6")[k % 2]]
        kill_at(["generate", str(spec), "-o", str(out)], token, float(delay))
        assert wait_until_gone(token) == [], f"kill {k}: workers outlived their parent"
        for name in names:
            if (out / name).exists():
                files = snapshot(out / name)
                assert files in (reference["0.6"][name], reference["1.4"][name]), (
                    f"kill {k}: {name} is neither complete generation: {_differences(files, reference, name)}"
                )
                held[name] += 1
        if out.exists():
            staged += sum(p.name.endswith(".lock") or ".partial-" in p.name for p in out.iterdir())
    print(
        f"{KILLS} kills of suite generation: complete sequences seen after them {held}, "
        f"leftovers of killed writers seen {staged}"
    )
    finish(["generate", str(versions["0.6"]), "-o", str(out)], token)
    for name in names:
        assert snapshot(out / name) == reference["0.6"][name]
    assert leftovers(out) == []


def _differences(files: dict[str, bytes], reference: dict, name: str) -> str:
    """Which files of a sequence differ from each reference generation (a half-swapped folder
    differs from both in many; a rendering mismatch in one frame of one)."""
    parts = []
    for speed, sequences in reference.items():
        expected = sequences[name]
        differ = sorted(f for f in set(files) | set(expected) if files.get(f) != expected.get(f))
        parts.append(f"against {speed}: {len(differ)} files differ ({', '.join(differ[:8])})")
    return "; ".join(parts)
