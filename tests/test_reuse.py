"""Reuse (issue 36 point 5): a sweep over an existing suite folder or a glob of sequence
folders, and the shared sequence store that copies a sequence rendered once wherever it
is asked for again (``run_suite``, a sweep's suite, the pytest plugin)."""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
from pathlib import Path

# Imported here, before any pytester fixture: pytester drops the modules a test imported when
# it ends, and numpy's C core cannot be loaded twice in one process.
import depotbench.eval.sweep.execute
import depotbench.scenes.generation
import depotbench.sim.generate  # noqa: F401
import pytest
from depotbench.core.errors import InputError
from depotbench.core.output import MARKER_NAME, OutputKind, OutputLock, StagedOutput, read_marker
from depotbench.eval.cli.main import main
from depotbench.eval.sweep.engine import named_sequences, validate
from depotbench.eval.sweep.spec import load_sweep
from depotbench.scenes.store import DEFAULT_MAX_BYTES, SequenceStore
from depotbench.scenes.suite import load_suite

from tests.sequences import tree_differences, write_sequence

SUITE = "suite: tiny\nbase: smoke\noverrides: {frames: 3}\ngrid: {actors.0.speed_mps: [0.6, 1.2]}\n"
"""Two sequences of three 160x120 frames, one knob besides the seed."""


@pytest.fixture(autouse=True)
def store(tmp_path: Path, monkeypatch) -> Path:
    """Each test's own sequence store: never the user's."""
    path = tmp_path / "store"
    monkeypatch.setenv("DEPOTBENCH_CACHE_SEQUENCES", str(path))
    monkeypatch.delenv("DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES", raising=False)
    return path


class Renders:
    """Counts the frames ``run_suite`` hands its render workers (it renders nowhere else)."""

    def __init__(self, monkeypatch) -> None:
        self.frames = 0
        real = depotbench.scenes.generation._generate_all

        def counted(pending, *args, **kwargs):
            self.frames += sum(sc.n_frames for _, sc in pending)
            return real(pending, *args, **kwargs)

        monkeypatch.setattr(depotbench.scenes.generation, "_generate_all", counted)


def _suite(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(SUITE)
    return path


def _summary(text: str) -> str:
    return next(line for line in text.splitlines() if " sequences: " in line)


@pytest.mark.render
def test_run_suite_twice_into_two_folders_renders_once_and_copies_byte_for_byte(
    tmp_path: Path, monkeypatch, caplog, store: Path
):
    caplog.set_level(logging.INFO, logger="depotbench")  # the suite's status lines are INFO
    renders = Renders(monkeypatch)
    path = _suite(tmp_path)
    depotbench.scenes.generation.run_suite(load_suite(path), path, tmp_path / "a", workers=2, progress=False)
    assert renders.frames == 6
    assert "0 from the store and 2 to generate" in _summary(caplog.text)
    caplog.clear()
    assert len([p for p in store.iterdir() if p.is_dir()]) == 2
    depotbench.scenes.generation.run_suite(load_suite(path), path, tmp_path / "b", workers=2, progress=False)
    assert renders.frames == 6  # none more
    assert "2 from the store and 0 to generate" in _summary(caplog.text)
    assert tree_differences(tmp_path / "a", tmp_path / "b") == []
    # A copy, not a link: editing one leaves the other (and the store) as it was.
    frame = next((tmp_path / "b" / "tiny-0000" / "rgb").iterdir())
    assert frame.stat().st_nlink == 1
    frame.write_bytes(b"edited")
    depotbench.scenes.generation.run_suite(load_suite(path), path, tmp_path / "c", workers=2, progress=False)
    assert tree_differences(tmp_path / "a", tmp_path / "c") == []


@pytest.mark.render
def test_a_sweep_over_a_generated_suite_folder_renders_nothing_and_keeps_the_suites_families(
    tmp_path: Path, monkeypatch, caplog
):
    """Before: a sweep could only generate its suite again (86 s of a 151 s sweep); a
    suite folder in ``sequences:`` was not a sequence folder."""
    caplog.set_level(logging.INFO, logger="depotbench")
    renders = Renders(monkeypatch)
    path = _suite(tmp_path)
    assert main(["generate", str(path), "-o", str(tmp_path / "suite"), "--workers", "2"]) == 0
    assert renders.frames == 6
    by_suite = tmp_path / "by-suite.yaml"
    by_suite.write_text("sweep: a\nsuite: tiny.yaml\nstrategies: [none]\n")
    by_folder = tmp_path / "by-folder.yaml"
    by_folder.write_text("sweep: b\nsequences: [suite]\nstrategies: [none]\n")
    rows = {}
    for spec_path in (by_suite, by_folder):
        spec = load_sweep(spec_path)
        validate(spec, spec_path)
        outcome = depotbench.eval.sweep.execute.execute_sweep(
            spec, spec_path, tmp_path / spec_path.stem, 1, progress=False, announce=False
        )
        rows[spec_path.stem] = sorted((r.family, r.knobs, r.seed) for r in outcome.records)
    assert renders.frames == 6  # the suite: sweep copied from the store, the other used the folder
    assert "2 from the store and 0 to generate" in caplog.text
    assert rows["by-folder"] == rows["by-suite"]
    assert rows["by-folder"] == [
        ("tiny actors.0.speed_mps=0.6", json.dumps({"actors.0.speed_mps": 0.6, "seed": 0}), 0),
        ("tiny actors.0.speed_mps=1.2", json.dumps({"actors.0.speed_mps": 1.2, "seed": 0}), 0),
    ]
    # Nothing was generated for the folder's sweep: its rows name the suite's own folders.
    assert not (tmp_path / "by-folder" / "sequences").exists()


def test_a_suite_folder_with_a_missing_or_stale_sequence_is_refused_before_any_output(tmp_path: Path):
    suite = tmp_path / "suite"
    write_sequence(suite / "s-0000", n=3, with_flow=False)
    (suite / MARKER_NAME).write_text(json.dumps({"kind": "suite", "tool": "depotbench"}))
    spec_path = tmp_path / "sweep.yaml"
    spec_path.write_text("sweep: s\nsequences: [suite]\nstrategies: [none]\n")
    with pytest.raises(InputError, match=r"sequences\.0: .*suite is a suite folder without index\.json"):
        validate(load_sweep(spec_path), spec_path)
    index = {"suite": "s", "sequences": [{"name": "s-0000", "knobs": {"seed": 0}, "content_key": "sha256:0"}]}
    (suite / "index.json").write_text(json.dumps(index))
    with pytest.raises(InputError, match=r"sequences\.0: .*s-0000 is not the complete sequence") as info:
        validate(load_sweep(spec_path), spec_path)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "out").exists()


def test_a_glob_in_sequences_takes_the_matching_folders_sorted_and_one_matching_nothing_is_refused(
    tmp_path: Path,
):
    for name in ("walk-b", "walk-a", "still"):
        write_sequence(tmp_path / "seqs" / name, n=3, with_flow=False)
    (tmp_path / "seqs" / "notes.txt").write_text("not a folder")
    spec_path = tmp_path / "sweep.yaml"
    spec_path.write_text("sweep: s\nsequences: ['seqs/walk-*', seqs/still]\nstrategies: [none]\n")
    spec = load_sweep(spec_path)
    validate(spec, spec_path)
    found = named_sequences(spec, spec_path)
    assert [e.root.name for e in found] == ["walk-a", "walk-b", "still"]
    everything = tmp_path / "all.yaml"
    everything.write_text("sweep: s\nsequences: ['seqs/*']\nstrategies: [none]\n")
    assert [e.root.name for e in named_sequences(load_sweep(everything), everything)] == [
        "still",
        "walk-a",
        "walk-b",
    ]
    missing = tmp_path / "missing.yaml"
    missing.write_text("sweep: s\nsequences: [seqs/still, 'nothing/*']\nstrategies: [none]\n")
    with pytest.raises(InputError, match=r"sequences\.1: 'nothing/\*' matches no folder") as info:
        validate(load_sweep(missing), missing)
    assert "\n" not in str(info.value)
    # Through the command line: one line, before the output folder is made.
    assert main(["sweep", str(missing), "-o", str(tmp_path / "out")]) != 0
    assert not (tmp_path / "out").exists()


def test_an_output_folder_inside_a_folder_a_glob_matched_is_refused(tmp_path: Path, capsys):
    """The spec's inputs listed the glob itself, so a sweep could write into a sequence."""
    write_sequence(tmp_path / "seqs" / "walk-a", n=3, with_flow=False)
    spec_path = tmp_path / "sweep.yaml"
    spec_path.write_text("sweep: s\nsequences: ['seqs/walk-*']\nstrategies: [none]\n")
    before = sorted(p.name for p in (tmp_path / "seqs" / "walk-a").iterdir())
    inside = tmp_path / "seqs" / "walk-a" / "out"
    assert main(["sweep", str(spec_path), "-o", str(inside)]) == 2
    assert "walk-a" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "seqs" / "walk-a").iterdir()) == before


PLUGIN_CONFTEST = """
from pathlib import Path

import depotbench.sim.generate  # noqa: F401

_generate = depotbench.sim.generate.generate


def _counted(scenario, out, **kwargs):
    with open({count!r}, "a") as handle:
        handle.write(f"{{scenario.frames}}\\n")
    return _generate(scenario, out, **kwargs)


depotbench.sim.generate.generate = _counted
"""


@pytest.mark.slow  # 15 s of two pytest sessions; the store is tested without the plugin by default
@pytest.mark.render
def test_the_plugins_second_session_with_a_fresh_dir_renders_nothing(pytester, tmp_path: Path):
    """Before: every session without the first one's --depotbench-dir rendered every
    sequence again (74 s)."""
    count = tmp_path / "frames-rendered"
    pytester.makeconftest(PLUGIN_CONFTEST.format(count=str(count)))
    pytester.makepyfile(
        """
        def test_run(depotbench_run):
            assert depotbench_run("smoke", strategy="box_rule", frames=3)["strategy"] == "box_rule"
        """
    )
    first = pytester.runpytest_subprocess(
        f"--depotbench-dir={tmp_path / 'first'}", "--depotbench-workers=1", "-p", "no:cacheprovider"
    )
    first.assert_outcomes(passed=1)
    assert count.read_text().split() == ["3"]
    second = pytester.runpytest_subprocess(  # no --depotbench-dir: a fresh temporary one
        "--depotbench-workers=1", "-p", "no:cacheprovider"
    )
    second.assert_outcomes(passed=1)
    assert count.read_text().split() == ["3"]  # nothing more rendered


@pytest.mark.render
def test_an_unwritable_store_costs_one_warning_line_and_the_run_goes_on(tmp_path: Path, monkeypatch, capsys):
    """A file where the store's folder should be (as root, a read-only folder is writable)."""
    (tmp_path / "file").write_text("not a folder")
    monkeypatch.setenv("DEPOTBENCH_CACHE_SEQUENCES", str(tmp_path / "file"))
    path = _suite(tmp_path)
    assert main(["generate", str(path), "-o", str(tmp_path / "out"), "--workers", "2"]) == 0
    err = capsys.readouterr().err.splitlines()
    warnings = [line for line in err if "warning" in line]
    assert len(warnings) == 1, err
    assert "sequence store" in warnings[0] and "Not a directory" in warnings[0]
    index = json.loads((tmp_path / "out" / "index.json").read_text())
    assert [read_marker(tmp_path / "out" / s["name"]).content_key for s in index["sequences"]] == [
        s["content_key"] for s in index["sequences"]
    ]


def _fake_sequence(root: Path, key: str, size: int) -> Path:
    """A folder marked as a complete sequence of ``key``: the store copies any files."""
    with StagedOutput(root, OutputKind.SEQUENCE, content_key=key) as out:
        (out.path / "rgb").mkdir()
        (out.path / "rgb" / "frame.png").write_bytes(os.urandom(size))
        (out.path / "meta.json").write_text("{}\n")
        out.commit()
    return root


def _key(i: int) -> str:
    return f"sha256:{i:064x}"


def test_the_store_evicts_the_least_recently_used_to_stay_under_its_bound(tmp_path: Path, store: Path):
    cache = SequenceStore(store, max_bytes=250_000)
    sources = [_fake_sequence(tmp_path / f"s{i}", _key(i), 100_000) for i in range(4)]
    assert cache.put(sources[0], _key(0)) and cache.put(sources[1], _key(1))
    os.utime(cache.entry(_key(0)), (1000, 1000))  # 0 older than 1 ...
    os.utime(cache.entry(_key(1)), (2000, 2000))
    assert cache.fetch(_key(0), tmp_path / "copy0")  # ... until it is used
    assert cache.put(sources[2], _key(2))
    assert [cache.has(_key(i)) for i in range(3)] == [True, False, True]
    assert cache.size_bytes() <= 250_000
    for i in range(4):  # at most two entries fit, whatever is put
        cache.put(sources[i], _key(i))
        assert cache.size_bytes() <= 250_000
        assert cache.has(_key(i))
    assert not [p for p in store.iterdir() if p.name.startswith(".")]  # nothing staged or set aside
    # What no bound can hold is not stored (it would evict everything, itself too).
    assert not SequenceStore(store, max_bytes=50_000).put(sources[0], _key(99))


def test_the_store_is_found_as_the_stage_cache_is_and_turned_off_as_it_is(tmp_path: Path, monkeypatch):
    monkeypatch.delenv("DEPOTBENCH_CACHE_SEQUENCES")
    monkeypatch.delenv("DEPOTBENCH_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    found = SequenceStore.from_env()
    assert found is not None and found.root == tmp_path / "xdg" / "depotbench" / "sequences"
    assert found.max_bytes == DEFAULT_MAX_BYTES
    monkeypatch.setenv("DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES", "500M")
    assert SequenceStore.from_env().max_bytes == 500 << 20
    monkeypatch.setenv("DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES", "lots")
    with pytest.raises(InputError, match="DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES"):
        SequenceStore.from_env()
    monkeypatch.delenv("DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES")
    for off in ("off", "OFF", "0", "no", "false"):
        monkeypatch.setenv("DEPOTBENCH_CACHE_SEQUENCES", off)
        assert SequenceStore.from_env() is None


def test_a_copy_is_never_taken_from_an_entry_evicted_while_it_is_copied(
    tmp_path: Path, store: Path, monkeypatch
):
    cache = SequenceStore(store)
    cache.put(_fake_sequence(tmp_path / "s", _key(1), 1000), _key(1))
    import depotbench.scenes.store as store_module

    real = store_module._copy_file

    def evicting(src, dst):
        SequenceStore(store, max_bytes=0).evict()  # another process evicts it midway
        return real(src, dst)

    monkeypatch.setattr(store_module, "_copy_file", evicting)
    assert not cache.fetch(_key(1), tmp_path / "copy")
    assert not (tmp_path / "copy").exists() and not list(tmp_path.glob(".copy*"))


def test_a_writer_of_a_key_being_stored_leaves_it_to_the_other_without_a_warning(
    tmp_path: Path, store: Path, caplog
):
    cache = SequenceStore(store)
    source = _fake_sequence(tmp_path / "s", _key(1), 1000)
    store.mkdir()
    with OutputLock(cache.entry(_key(1))):  # another process is storing it
        assert not cache.put(source, _key(1))
    assert cache.writable and not caplog.records
    assert cache.put(source, _key(1)) and cache.has(_key(1))
    # PNGs written at another zlib level are other bytes (the same pixels): not this entry.
    assert not cache.has(_key(1), png_compression=0)
    assert not cache.fetch(_key(1), tmp_path / "copy", png_compression=0)


def _put(store: str, source: str, key: str) -> bool:
    return SequenceStore(Path(store)).put(Path(source), key)


def test_concurrent_writers_of_one_key_leave_one_whole_entry(tmp_path: Path, store: Path):
    source = _fake_sequence(tmp_path / "s", _key(7), 4 << 20)
    context = multiprocessing.get_context("spawn")
    with context.Pool(4) as pool:
        stored = pool.starmap(_put, [(str(store), str(source), _key(7))] * 8)
    assert any(stored)
    entry = SequenceStore(store).entry(_key(7))
    assert sorted(p.name for p in store.iterdir()) == [entry.name, f"{entry.name}.json"]
    assert SequenceStore(store).fetch(_key(7), tmp_path / "copy")
    assert tree_differences(source, tmp_path / "copy") == []


def test_an_entry_written_before_the_bench_set_numpys_cpu_code_is_never_read_only_evicted(
    tmp_path: Path, store: Path
):
    """Until 2026-12-04 an AVX-512 machine stored its own bytes under a key (numpy's and
    OpenBLAS's AVX-512 code, docs/determinism.md); entries since carry ``-r2``. An older entry
    (``HEX-L``) is not taken for its key, and the bound evicts it as any other."""
    from depotbench.scenes.store import ENTRY_SUFFIX

    cache = SequenceStore(store, max_bytes=150_000)
    assert cache.put(_fake_sequence(tmp_path / "s0", _key(0), 100_000), _key(0))
    entry = cache.entry(_key(0))
    assert entry.name.endswith(ENTRY_SUFFIX)
    old = entry.with_name(entry.name.removesuffix(ENTRY_SUFFIX))
    entry.rename(old)
    entry.with_name(entry.name + ".json").rename(old.with_name(old.name + ".json"))
    os.utime(old, (1000, 1000))
    assert not cache.has(_key(0)) and not cache.fetch(_key(0), tmp_path / "copy")
    assert [e.path for e in cache.entries()] == [old]
    assert cache.put(_fake_sequence(tmp_path / "s1", _key(1), 100_000), _key(1))  # evicts the old one
    assert not old.exists() and cache.has(_key(1))


def test_a_process_whose_numpy_loaded_before_the_bench_neither_reads_nor_writes_the_store(tmp_path: Path):
    """Its sequences are its machine's own bytes where the CPU has AVX-512 (core/numerics.py)."""
    import subprocess
    import sys

    from depotbench.core.numerics import reference_environment

    code = (
        "import numpy\nfrom depotbench.scenes.store import SequenceStore\n"
        "print(SequenceStore.from_env() is None)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in reference_environment()}
    env["DEPOTBENCH_CACHE"] = str(tmp_path / "cache")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(bool(reference_environment()))


def test_a_suites_workers_use_the_store_unless_the_user_set_other_numerics(tmp_path: Path):
    """Suites render in spawned workers, which the pool gives the reference variables: the
    store serves them even where this process loaded numpy first, but not where the user set
    a variable otherwise (their bytes are then the machine's own, on an AVX-512 CPU)."""
    import subprocess
    import sys

    from depotbench.core.numerics import reference_environment

    code = (
        "import numpy\nfrom depotbench.scenes.store import SequenceStore\n"
        "print(SequenceStore.from_env(workers=True) is None)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in reference_environment()}
    env["DEPOTBENCH_CACHE"] = str(tmp_path / "cache")
    for forced, refused in (({}, False), ({"NPY_DISABLE_CPU_FEATURES": ""}, bool(reference_environment()))):
        done = subprocess.run(
            [sys.executable, "-c", code], env={**env, **forced}, capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0, done.stderr
        assert done.stdout.strip() == str(refused), forced
