"""A lock names the machine and libraries that froze each sequence, so that a sequence made
with other bytes elsewhere is refused naming both machines (docs/determinism.md: a machine
of another CPU made other bytes with the same libraries, and each OpenCV draws its own)."""

from __future__ import annotations

import json
from importlib import metadata
from pathlib import Path

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.benchmark import sequences as bench_sequences
from depotbench.eval.benchmark.spec import load_benchmark, lock_path, write_lock
from depotbench.sim.machine import machine_kind, machine_summary

from tests.smoke_lock import copy_of_smoke


def test_the_summary_names_the_cpu_class_and_the_libraries_installed():
    line = machine_summary()
    flags = set()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        flags = {
            f for row in cpuinfo.read_text().splitlines() if row.startswith("flags") for f in row.split()
        }
    assert ("(avx512)" in line) == ("avx512f" in flags)
    for name, distribution in (
        ("opencv", "opencv-python-headless"),
        ("mujoco", "mujoco"),
        ("numpy", "numpy"),
    ):
        assert f"{name} {metadata.version(distribution)}" in line


def test_a_lock_keeps_each_sequences_machine_and_an_older_lock_names_none(tmp_path: Path):
    path = copy_of_smoke(tmp_path)
    data = json.loads(lock_path(path).read_text())
    for entry in data["sequences"]:
        del entry["frozen_on"]  # as a lock written before the field
    lock_path(path).write_text(json.dumps(data))
    old = load_benchmark(path)
    assert all(s.frozen_on is None for s in old.sequences)
    marked = [s.__class__(**{**s.__dict__, "frozen_on": f"machine {i}"}) for i, s in enumerate(old.sequences)]
    write_lock(path, old.spec, marked)
    again = load_benchmark(path)
    assert [s.frozen_on for s in again.sequences] == ["machine 0", "machine 1", "machine 2"]
    assert [s.files_key for s in again.sequences] == [s.files_key for s in old.sequences]
    data = json.loads(lock_path(path).read_text())
    assert data["sequences"][0]["frozen_on"] == "machine 0"


def test_a_sequence_with_other_bytes_is_refused_naming_both_machines(tmp_path: Path, monkeypatch):
    """prepare() with generation and hashing stood in for: the hash is not the lock's."""
    path = copy_of_smoke(tmp_path)
    old = load_benchmark(path)
    marked = [
        s.__class__(**{**s.__dict__, "frozen_on": "Xeon (avx512); opencv 5.1.0.95"}) for s in old.sequences
    ]
    write_lock(path, old.spec, marked)
    monkeypatch.setattr(bench_sequences, "_generate", lambda *args, **kwargs: None)
    monkeypatch.setattr("depotbench.sim.sequence.Sequence.open", staticmethod(lambda folder: folder))
    monkeypatch.setattr("depotbench.eval.run.detections.sequence_fingerprint", lambda sequence: "0" * 32)
    with pytest.raises(InputError) as refused:
        bench_sequences.prepare(load_benchmark(path), tmp_path / "sequences", workers=1, progress=False)
    text = str(refused.value)
    assert "smoke/smoke-0000" in text and "frozen on Xeon (avx512); opencv 5.1.0.95" in text
    assert f"this is {machine_summary()}" in text and len(text.splitlines()) == 1


def test_the_tests_take_other_bytes_than_the_locks_only_from_a_machine_of_another_kind(
    tmp_path: Path, monkeypatch
):
    """tests/smoke_lock.py: where the lock refuses smoke-1's bytes and a sequence with other
    bytes was frozen on a machine with this CPU and renderer (the libraries aside), the
    generator changed and the refusal stands; so does a refusal that names another machine
    as this one."""
    from tests import smoke_lock

    frozen = load_benchmark("smoke-1").sequences[0].frozen_on
    same_kind = machine_kind(frozen) + "; opencv 5.1.0.95, mujoco 9.9.9, numpy 2.4.6"
    refusal = f"smoke-0000: its files are not smoke-1's (frozen on {frozen}; this is {same_kind}; docs)"

    def refuse(*args, **kwargs):
        raise InputError(refusal)

    monkeypatch.setattr(smoke_lock, "prepare", refuse)
    monkeypatch.setattr(smoke_lock, "other_bytes", lambda *args: {"smoke/smoke-0000": (frozen,)})
    monkeypatch.setattr(smoke_lock, "machine_summary", lambda: same_kind)
    with pytest.raises(InputError, match="its files are not smoke-1's"):
        smoke_lock.smoke_1(tmp_path)
    monkeypatch.setattr(smoke_lock, "other_bytes", lambda *args: {"smoke/smoke-0000": (None,)})
    with pytest.raises(InputError, match="its files are not smoke-1's"):  # frozen on a machine unnamed
        smoke_lock.smoke_1(tmp_path)
    monkeypatch.setattr(smoke_lock, "machine_summary", lambda: "Xeon (avx512); softpipe; opencv 5.1.0.95")
    with pytest.raises(AssertionError):  # the refusal names another machine than this one
        smoke_lock.smoke_1(tmp_path)
    assert not (tmp_path / "frozen-here").exists()


def test_a_lock_accepts_the_keys_of_several_machine_kinds_and_names_them_all(tmp_path: Path, monkeypatch):
    """``also``: keys of the same spec frozen on machines of other kinds (benchmarks/freeze.py
    --add-machine). A sequence with one of them is taken; one with none is refused naming
    every machine; the lock is read back as written."""
    path = copy_of_smoke(tmp_path)
    old = load_benchmark(path)
    other = ("1" * 32, "Xeon (avx512); llvmpipe (LLVM 15.0.6, 256 bits), Mesa 22.3.6; opencv 5.1.0.95")
    marked = [s.__class__(**{**s.__dict__, "also": (other,)}) for s in old.sequences]
    write_lock(path, old.spec, marked)
    again = load_benchmark(path)
    assert again.sequences == tuple(marked)
    assert json.loads(lock_path(path).read_text())["sequences"][0]["also"] == [
        {"files_key": other[0], "frozen_on": other[1]}
    ]
    monkeypatch.setattr(bench_sequences, "_generate", lambda *args, **kwargs: None)
    monkeypatch.setattr("depotbench.sim.sequence.Sequence.open", staticmethod(lambda folder: folder))
    monkeypatch.setattr("depotbench.eval.run.detections.sequence_fingerprint", lambda sequence: "1" * 32)
    taken = bench_sequences.prepare(again, tmp_path / "sequences", workers=1, progress=False)
    assert [p.files_key for p in taken] == ["1" * 32] * 3
    monkeypatch.setattr("depotbench.eval.run.detections.sequence_fingerprint", lambda sequence: "2" * 32)
    with pytest.raises(InputError) as refused:
        bench_sequences.prepare(again, tmp_path / "sequences", workers=1, progress=False)
    text = str(refused.value)
    assert f"the lock's {old.sequences[0].files_key} or {'1' * 32}" in text
    assert f"frozen on {old.sequences[0].frozen_on}; or on {other[1]}; this is {machine_summary()}" in text
    assert len(text.splitlines()) == 1


def test_a_lock_whose_sequence_has_other_machines_keys_but_none_of_its_own_is_refused(tmp_path: Path):
    path = copy_of_smoke(tmp_path)
    data = json.loads(lock_path(path).read_text())
    data["sequences"][0]["files_key"] = None
    data["sequences"][0]["also"] = [{"files_key": "1" * 32, "frozen_on": "Xeon"}]
    lock_path(path).write_text(json.dumps(data))
    with pytest.raises(InputError, match="has none of its own"):
        load_benchmark(path)


def test_benchmark_list_says_which_machine_kinds_each_benchmark_holds_and_this_ones_count(capsys):
    """Before generating anything a user sees whether this kind of machine can score a
    benchmark: per kind, how many sequences hold its bytes (read here from the lock files)."""
    from depotbench.eval.cli.main import main

    assert main(["benchmark", "list", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    here = machine_kind(machine_summary())
    assert listed["machine"] == here
    for entry in listed["benchmarks"]:
        lock = json.loads(lock_path(load_benchmark(entry["name"]).path).read_text())
        kinds: dict[str, set[str]] = {}
        for s in lock["sequences"]:
            named = [s.get("frozen_on")] + [a["frozen_on"] for a in s.get("also", [])]
            for on in named:
                if on is not None and s["files_key"] is not None:
                    kinds.setdefault(machine_kind(on), set()).add(s["name"])
        assert entry["machines"] == {k: len(v) for k, v in kinds.items()}, entry["name"]
        assert entry["here"] == len(kinds.get(here, ()))
    assert main(["benchmark", "list"]) == 0
    text = capsys.readouterr().out
    smoke = next(e for e in listed["benchmarks"] if e["name"] == "smoke-1")
    assert f"; {smoke['here']} frozen on this kind of machine" in text
    assert ("(this kind)" in text) == any(e["here"] for e in listed["benchmarks"])


def test_an_avx512_cpu_is_of_the_kind_of_the_same_model_with_avx2():
    """The bench runs numpy's and OpenBLAS's AVX2 code on an AVX-512 CPU (core/numerics.py):
    an AVX-512 EPYC then generated the AVX2 EPYC's bytes, so a lock frozen on one holds for
    the other, and other bytes there are the generator's."""
    renderer = "llvmpipe (LLVM 15.0.6, 256 bits), Mesa 22.3.6"
    avx512 = f"AMD EPYC (avx512); {renderer}; opencv 5.1.0.95, mujoco 4.0.1, numpy 2.4.6"
    avx2 = f"AMD EPYC (avx2, no avx512); {renderer}; opencv 5.1.0.95, mujoco 4.0.0, numpy 2.4.6"
    assert machine_kind(avx512) == machine_kind(avx2) == f"AMD EPYC (avx2); {renderer}"
    assert machine_kind(f"AMD EPYC (no avx2); {renderer}") != machine_kind(avx2)
    assert machine_kind(avx2.replace("llvmpipe", "softpipe")) != machine_kind(avx2)
