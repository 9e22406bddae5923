"""Sweeps on a Ray cluster whose nodes share no folder (docs/cluster.md).

The default run checks the pieces on one process: a sequence packed by the driver unpacks
on a node to the same files key; a node makes each sequence once, from its own store or the
copy, and refuses bytes other than the driver's; a node whose program differs fails its
jobs with one line. The slow suite starts a real cluster on this machine (a head and two
worker nodes, each in a mount namespace where the driver's folders and the other node's
are empty tmpfs mounts) and runs sweeps on it: the rows are those of one machine, with a
worker node killed mid-sweep too.
"""

from __future__ import annotations

import importlib.util
import os
import shlex
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS
from depotbench.eval.run import nodes
from depotbench.eval.run.detections import sequence_fingerprint
from depotbench.eval.run.nodes import SequenceSource, local_sequence
from depotbench.eval.sweep.store import ResultStore
from depotbench.scenes.shipping import pack, unpack
from depotbench.sim.sequence import Sequence

from tests.conftest import REPO, benchmark_module
from tests.sequences import write_sequence
from tests.smoke_lock import smoke_1


def _files_key(root: Path) -> str:
    return sequence_fingerprint(Sequence.open(root))


@pytest.fixture
def node(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict:
    """This process as a cluster's node: its own cache root, and a stand-in for Ray whose
    ``get`` hands back what was "put" (the packed bytes) and counts the fetches."""
    fetched: list[bytes] = []

    def get(ref):
        if ref is None:
            raise AssertionError("the node fetched a sequence it should have had")
        fetched.append(ref)
        return ref

    monkeypatch.setitem(sys.modules, "ray", types.SimpleNamespace(get=get, is_initialized=lambda: False))
    monkeypatch.setenv("DEPOTBENCH_CACHE", str(tmp_path / "node-cache"))
    monkeypatch.setattr(nodes, "_LOCAL", {})
    return {"fetched": fetched, "root": tmp_path / "node-cache"}


def test_a_packed_sequence_unpacks_elsewhere_to_the_same_files_key_and_name(tmp_path: Path):
    write_sequence(tmp_path / "rgbd_dataset_freiburg3_x", n=4)
    (tmp_path / "rgbd_dataset_freiburg3_x" / "notes.bag").write_bytes(b"x" * 1000)  # not the format's
    data = pack(tmp_path / "rgbd_dataset_freiburg3_x")
    made = unpack(data, tmp_path / "node" / "abc")
    assert made == tmp_path / "node" / "abc" / "rgbd_dataset_freiburg3_x"  # a TUM camera is guessed by name
    assert _files_key(made) == _files_key(tmp_path / "rgbd_dataset_freiburg3_x")
    assert not (made / "notes.bag").exists()
    assert not [p for p in (tmp_path / "node").iterdir() if p.name != "abc"]  # no staging left


def test_a_node_makes_a_sequence_once_checks_it_and_makes_a_damaged_one_again(tmp_path: Path, node: dict):
    write_sequence(tmp_path / "seq", n=4)
    key = _files_key(tmp_path / "seq")
    source = SequenceSource(key, "seq", None, pack(tmp_path / "seq"))
    path = local_sequence(source)
    assert path == node["root"] / "shipped" / key / "seq" and _files_key(path) == key
    assert local_sequence(source) == path and len(node["fetched"]) == 1  # this process: once
    nodes._LOCAL.clear()  # another worker process of the node: finds it made
    assert local_sequence(source) == path and len(node["fetched"]) == 1
    nodes._LOCAL.clear()
    first_rgb = sorted((path / "rgb").iterdir())[0]
    first_rgb.write_bytes(first_rgb.read_bytes()[:-1])  # damaged on the node
    assert local_sequence(source) == path and len(node["fetched"]) == 2 and _files_key(path) == key

    other = SequenceSource("0" * 32, "seq", None, pack(tmp_path / "seq"))  # the driver saw other bytes
    with pytest.raises(InputError) as refused:
        local_sequence(other)
    message = str(refused.value)
    assert message.startswith("node ") and "sequence seq made here holds other files" in message
    assert "\n" not in message


@pytest.mark.render
def test_a_generated_sequence_the_nodes_store_holds_is_taken_from_it_not_the_driver(
    tmp_path: Path, node: dict, monkeypatch: pytest.MonkeyPatch
):
    from depotbench.core.files import DEFAULT_PNG_COMPRESSION
    from depotbench.core.output import OutputKind
    from depotbench.scenes.schema import to_scenario
    from depotbench.scenes.shipping import render_on_node, unpack_output
    from depotbench.scenes.store import SequenceStore
    from depotbench.scenes.suite import load_suite, variations
    from depotbench.sim.spec import content_key

    monkeypatch.delenv("DEPOTBENCH_CACHE_SEQUENCES", raising=False)  # the node's store, on
    suite = tmp_path / "s.yaml"
    suite.write_text("suite: s\nbase: smoke\noverrides: {frames: 3}\nseeds: [5]\n")
    ((name, _, scenario),) = variations(load_suite(suite), suite)
    packed = render_on_node(scenario.model_dump(mode="json"), name, DEFAULT_PNG_COMPRESSION)
    key = content_key(to_scenario(scenario))
    assert SequenceStore.from_env().has(key)
    unpack_output(
        packed, tmp_path / "driver" / name, OutputKind.SEQUENCE, key
    )  # what the driver writes of it
    files_key = _files_key(tmp_path / "driver" / name)
    path = local_sequence(SequenceSource(files_key, name, key, None))  # None: fetching would fail
    assert _files_key(path) == files_key and node["fetched"] == []


def test_a_node_whose_program_differs_from_the_drivers_fails_its_jobs_in_one_line(tmp_path: Path):
    from depotbench.eval.sweep.engine import expand
    from depotbench.eval.sweep.spec import load_sweep

    write_sequence(tmp_path / "seq", n=4)
    program = tmp_path / "my_slam.py"
    program.write_text("print('v1')\n")
    spec = tmp_path / "spec.yaml"
    command = f"{shlex.quote(sys.executable)} {program} {{sequence}} {{trajectory}}"
    spec.write_text(
        f"sweep: s\nsequences: [{tmp_path / 'seq'}]\ntrackers:\n  - name: mine\n    command: {command!r}\n"
    )
    (job,) = expand(load_sweep(spec), spec, [(tmp_path / "seq", "f")])
    assert nodes.program_differs(job.job.tracker, job.run.tracker_fingerprint) is None
    program.write_text("print('v2')\n")  # this node holds another version
    nodes._PROGRAMS.clear()
    message = nodes.program_differs(job.job.tracker, job.run.tracker_fingerprint)
    assert message is not None and message.startswith("node ") and "\n" not in message
    assert "tracker mine's program or the files its command names differ from the driver's" in message


def test_a_node_with_another_depotbench_fails_its_built_in_jobs_in_one_line(tmp_path: Path, monkeypatch):
    """The built-in's program is the node's depotbench: another release (or a checkout's
    driver beside nodes that installed a release) would write its rows under the driver's
    keys. Before the built-in's fingerprint carried ``code_version``, nodes were not asked."""
    from depotbench.core import version
    from depotbench.eval.sweep.engine import _dispatch, _on_node, expand, run_branches
    from depotbench.eval.sweep.spec import load_sweep

    write_sequence(tmp_path / "seq", n=4)
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"sweep: s\nsequences: [{tmp_path / 'seq'}]\nstrategies: [none, box_rule]\n")
    jobs = expand(load_sweep(spec), spec, [(tmp_path / "seq", "f")])
    assert len(jobs) == 2 and all(not j.job.tracker.type.external for j in jobs)
    nodes._PROGRAMS.clear()
    assert nodes.program_differs(jobs[0].job.tracker, jobs[0].run.tracker_fingerprint) is None
    monkeypatch.setattr(version, "source_digest", lambda: "0123456789ab")  # this node's other code
    nodes._PROGRAMS.clear()
    message = nodes.program_differs(jobs[0].job.tracker, jobs[0].run.tracker_fingerprint)
    assert message is not None and message.startswith("node ") and "\n" not in message
    assert "its depotbench (" in message and "is not the driver's" in message
    # a branching task of the sweep's phase 2 gives a failed row per job, tracking nothing
    task = (run_branches, (jobs, [(), ()], ["a", "b"], "0.8.0"))
    monkeypatch.setattr(  # the sequence is on this machine: nothing shipped to make locally
        "depotbench.eval.sweep.engine._localized", lambda value, sources: value
    )
    failures = _on_node(_dispatch, {}, task)
    assert [f.record.failure for f in failures] == [message, message]
    nodes._PROGRAMS.clear()


def test_the_driver_puts_a_sequence_when_its_first_job_is_taken_and_lets_it_go_after_its_last(
    tmp_path: Path,
):
    """Ray frees an object once no one holds its reference: the driver holds a sequence's
    only while jobs that need it are still to be taken."""
    import gc
    import weakref

    from depotbench.eval.run.nodes import Shipments

    class Ref:  # what ray.put returns, here
        pass

    for name in ("a", "b"):
        write_sequence(tmp_path / name, n=2)
    refs: dict[str, weakref.ref] = {}

    def put(data: bytes) -> Ref:
        ref = Ref()
        refs["a" if not refs else "b"] = weakref.ref(ref)
        return ref

    shipments = Shipments(put, {str(tmp_path / n): n for n in "ab"})
    taken = shipments.around([{"a"}, {"a"}, {"b"}], lambda item: {str(tmp_path / n) for n in item})
    first = next(taken)
    assert list(refs) == ["a"] and first[1][str(tmp_path / "a")].fingerprint == "a"  # b not yet
    second = next(taken)
    assert second[1][str(tmp_path / "a")] is first[1][str(tmp_path / "a")]  # put once
    del first, second  # the jobs submitted (Ray holds their arguments while they run)
    third = next(taken)
    gc.collect()
    assert refs["a"]() is None and refs["b"]() is third[1][str(tmp_path / "b")].packed
    assert list(taken) == [] and shipments.put_count == 2


def test_a_clusters_nodes_keep_their_own_cache_folders():
    from depotbench.core.executors import _names_a_folder_here

    assert _names_a_folder_here("DEPOTBENCH_CACHE") and _names_a_folder_here("DEPOTBENCH_CACHE_STAGES")
    assert not _names_a_folder_here("DEPOTBENCH_KERNELS")


# -- a cluster of three Ray nodes on this machine (slow) ---------------------------------------

SUITE = "suite: walk\nbase: smoke\noverrides: {frames: 6}\nseeds: [11, 12]\n"
SWEEP = """\
sweep: cluster
sequences: [{a}, {b}]
suite: suite.yaml
detectors: [groundtruth, {{detector: groundtruth, faults: {{miss: 0.5}}}}]
strategies: [none, box_rule, prior_flow]
thresholds:
  prior_flow: {{k: {{grid: [1.5, 2.5, 3.5]}}}}
"""
"""4 sequences (2 of the user's, 2 generated) x 2 detectors x (none, box_rule, 3 k) = 40 runs."""


def _cluster_unavailable() -> str | None:
    if importlib.util.find_spec("ray") is None:
        return "Ray is the [ray] extra"
    return benchmark_module("local_cluster").can_hide_folders()


def _rows(database: Path) -> list[dict]:
    with ResultStore(database) as store:
        return sorted(({k: r[k] for k in DETERMINISTIC_FIELDS} for r in store.rows()), key=lambda r: r["key"])


def _count(database: Path) -> int:
    try:
        with sqlite3.connect(f"file:{database}?mode=ro", uri=True) as db:
            return db.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
    except sqlite3.Error:
        return 0


def _sweep(
    spec: Path, out: Path, env: dict, address: str | None = None, quiet: bool = True
) -> subprocess.Popen:
    args = [sys.executable, "-m", "depotbench.eval.cli.main", "sweep", str(spec), "-o", str(out)]
    args += ["-q"] if quiet else []
    args += ["--workers", "2"] + (["--backend", "ray", "--address", address] if address else [])
    out = None if quiet else subprocess.PIPE  # the tasks-per-node lines come with the results
    return subprocess.Popen(
        args, env=os.environ | env, cwd=REPO, stdout=out, stderr=subprocess.PIPE, text=True
    )


@pytest.mark.slow
@pytest.mark.render
def test_a_sweep_on_nodes_that_share_no_folder_gives_one_machines_rows_and_survives_a_dead_node(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
):
    """The driver's folders (its sequences, suite, sweep folders and caches) are empty tmpfs
    mounts on both worker nodes, and each node's cache is empty to the other: every job must
    get its sequence through Ray. Run 1: the whole sweep on the cluster equals the local
    sweep row for row and its generated suite byte for byte. Run 2: worker node 0 is killed
    (SIGKILL, its raylet and workers) once rows start to come back; its jobs run again on
    node 1 and the rows are the same again. Run 3: the driver is killed (SIGKILL) mid-sweep
    and run again: it runs what is missing and the rows are the same again. Then smoke-1 is
    scored on the cluster: the figures and trajectories of one machine."""
    unavailable = _cluster_unavailable()
    if unavailable:
        pytest.skip(unavailable)
    local_cluster = benchmark_module("local_cluster")
    smoke = smoke_1(tmp_path / "smoke")  # as this machine names it: tests/smoke_lock.py
    driver = tmp_path / "driver"
    for name, seed in (("a", 0), ("b", 1)):
        write_sequence(driver / name, n=10, seed=seed, with_flow=False)
    (driver / "suite.yaml").write_text(SUITE)
    spec = driver / "spec.yaml"
    spec.write_text(SWEEP.format(a=driver / "a", b=driver / "b"))
    local = _sweep(spec, driver / "local", {})
    assert local.wait() == 0, local.stderr.read()
    expected = _rows(driver / "local" / "results.sqlite")
    assert len(expected) == 40

    session_caches = Path(os.environ["DEPOTBENCH_CACHE"])
    nodes = tmp_path_factory.mktemp("nodes")  # outside the driver's folders, which the nodes lose
    with local_cluster.LocalCluster(nodes, workers=2, hide=[driver, session_caches]) as cluster:
        started = time.perf_counter()
        whole = _sweep(spec, driver / "cluster", cluster.driver_env, cluster.address, quiet=False)
        said = "".join(whole.communicate(timeout=600))
        assert whole.returncode == 0, said
        whole_s = time.perf_counter() - started
        per_node = [line for line in said.splitlines() if "tasks per node" in line]
        assert len(per_node) == 2  # the suite's generation, the sweep's jobs
        assert _rows(driver / "cluster" / "results.sqlite") == expected
        for name in ("walk-0000", "walk-0001"):
            assert _files_key(driver / "cluster" / "sequences" / name) == _files_key(
                driver / "local" / "sequences" / name
            )
        made = {
            i: sorted(p.name for p in (nodes / f"node{i}" / "cache" / "shipped").glob("*")) for i in (0, 1)
        }
        shipped = sum(
            f.stat().st_size
            for i in (0, 1)
            for f in (nodes / f"node{i}" / "cache" / "shipped").rglob("*")
            if f.is_file()
        )
        counts = [len(m) for m in made.values()]
        print(f"cluster sweep: 40 runs in {whole_s:.1f} s; sequences made per node {counts}, {shipped} bytes")
        print("\n".join(per_node))

        killed = _sweep(spec, driver / "killed", cluster.driver_env, cluster.address)
        while _count(driver / "killed" / "results.sqlite") < 5 and killed.poll() is None:
            time.sleep(0.2)
        assert killed.poll() is None and _count(driver / "killed" / "results.sqlite") < 40
        cluster.kill_node(0)  # mid-sweep: its jobs in flight run again on node 1
        assert killed.wait(600) == 0, killed.stderr.read()
        assert _rows(driver / "killed" / "results.sqlite") == expected

        dead = _sweep(spec, driver / "resumed", cluster.driver_env, cluster.address)  # the driver dies
        while _count(driver / "resumed" / "results.sqlite") < 5 and dead.poll() is None:
            time.sleep(0.2)
        assert dead.poll() is None
        dead.send_signal(signal.SIGKILL)
        dead.wait()
        kept = _count(driver / "resumed" / "results.sqlite")
        resumed = _sweep(spec, driver / "resumed", cluster.driver_env, cluster.address)
        assert resumed.wait(600) == 0, resumed.stderr.read()
        assert 5 <= kept < 40 and _rows(driver / "resumed" / "results.sqlite") == expected

        # a benchmark: its sequences rendered on the nodes, its runs' folders sent back
        bench = _benchmark(smoke, driver / "bench-cluster", cluster.driver_env, cluster.address)
    assert bench == _benchmark(smoke, driver / "bench-local", {})
    # the stopped head's /tmp/ray/ray_current_cluster would make a later local Ray refuse to start
    assert not (Path(tempfile.gettempdir()) / "ray" / "ray_current_cluster").exists()


def _benchmark(smoke: str, out: Path, env: dict, address: str | None = None) -> list:
    """smoke-1 scored by the built-in tracker: each run's figures and trajectory's hash."""
    import json

    args = [sys.executable, "-m", "depotbench.eval.cli.main", "benchmark", "run", smoke, "-o", str(out)]
    args += ["-q", "--workers", "2"] + (["--backend", "ray", "--address", address] if address else [])
    done = subprocess.run(args, env=os.environ | env, cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    results = json.loads((out / "results.json").read_text())
    runs = [(s["name"], s["files_key"], r) for s in results["sequences"] for r in s["runs"]]
    assert len(runs) == 3 and all(r["status"] == "ok" for _, _, r in runs)
    assert all((out / r["folder"] / "trajectory.txt").is_file() for _, _, r in runs)
    return [(name, key, r["figures"], r["trajectory_sha256"]) for name, key, r in runs]
