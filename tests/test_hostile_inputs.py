"""Hostile inputs to the readers of markers, manifests, indexes and caches (issue 50 item 8,
reliability probe 2): a FIFO, a device or an oversized file is refused in one line without
blocking, a damaged cache entry is recomputed, and a store entry edited in place is never
served under its content key."""

from __future__ import annotations

import contextlib
import io
import logging
import os
import signal
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from depotbench.core.cache_home import CACHES, RETIRED, ROOT_VARIABLE
from depotbench.core.errors import InputError
from depotbench.core.output import MARKER_NAME, OutputKind, StagedOutput, read_marker
from depotbench.eval.cli.main import main
from depotbench.eval.run.cache import StageCache, content_hash
from depotbench.scenes.schema import SpecError, read_yaml
from depotbench.scenes.store import SequenceStore

VARIABLES = (
    ROOT_VARIABLE,
    "XDG_CACHE_HOME",
    *RETIRED,
    *(c.variable for c in CACHES.values()),
    *(c.bound_variable for c in CACHES.values() if c.bound_variable),
)
KEY = "sha256:" + "ab" * 32


class Blocked(BaseException):
    """Raised by the alarm: no reader's ``except OSError`` (``TimeoutError``) or ``except
    Exception`` takes it for a failure of its own."""


@contextlib.contextmanager
def _within(seconds: int) -> Iterator[None]:
    """Fail, instead of hanging the suite, when the block blocks (a FIFO opened for reading
    waits for a writer that never comes)."""

    def expired(signum, frame):
        raise Blocked(f"blocked for more than {seconds} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _one_line(err: str, *needles: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def _fake_sequence(root: Path, key: str = KEY, frames: int = 3) -> Path:
    """A folder marked as a complete sequence of ``key``: the store copies any files."""
    with StagedOutput(root, OutputKind.SEQUENCE, content_key=key) as out:
        (out.path / "rgb").mkdir()
        for i in range(frames):
            (out.path / "rgb" / f"{i}.png").write_bytes(os.urandom(2000))
        (out.path / "groundtruth.txt").write_text("1.0 0 0 0 0 0 0 1\n")
        out.commit()
    return root


# -- N8: markers ---------------------------------------------------------------------------------


def test_a_fifo_marker_is_no_marker_and_blocks_nothing(tmp_path: Path):
    os.mkfifo(tmp_path / MARKER_NAME)
    with _within(2):
        assert read_marker(tmp_path) is None


def test_run_overwrite_onto_a_folder_with_a_fifo_marker_is_refused_not_hung(tmp_path: Path, capsys):
    from tests.sequences import write_sequence

    write_sequence(tmp_path / "seq", n=3)
    (tmp_path / "out").mkdir()
    os.mkfifo(tmp_path / "out" / MARKER_NAME)
    with _within(20):
        code = main(["run", str(tmp_path / "seq"), "-o", str(tmp_path / "out"), "--overwrite"])
    assert code == 2
    _one_line(capsys.readouterr().err, str(tmp_path / "out"))


# -- N9, N17, N7: the sequence store -------------------------------------------------------------


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_manifest_that_is_no_regular_file_is_a_missing_entry(tmp_path: Path, kind: str):
    store = SequenceStore(tmp_path / "store", max_bytes=1 << 30)
    assert store.put(_fake_sequence(tmp_path / "seq"), KEY)
    entry = store.entry(KEY)
    assert entry is not None
    manifest = entry.with_name(entry.name + ".json")
    manifest.unlink()
    if kind == "fifo":
        os.mkfifo(manifest)
    else:
        manifest.symlink_to("/dev/zero")
    with _within(5):
        assert not store.has(KEY)
        assert not store.fetch(KEY, tmp_path / "copy")
        assert store.size_bytes() > 0  # listed by measuring the folder
        assert store.put(tmp_path / "seq", KEY)  # and stored again, whole
    assert store.fetch(KEY, tmp_path / "copy")


def test_a_bound_lowered_below_an_entry_evicts_it_instead_of_serving_it(tmp_path: Path):
    """Probe N17: with ``..._MAX_BYTES=0`` the store kept and served its entries."""
    assert SequenceStore(tmp_path / "store", max_bytes=1 << 30).put(_fake_sequence(tmp_path / "seq"), KEY)
    lowered = SequenceStore(tmp_path / "store", max_bytes=0)
    assert not lowered.fetch(KEY, tmp_path / "copy")
    assert lowered.entries() == []
    assert not (tmp_path / "copy").exists()


@pytest.mark.parametrize("edit", ["same size", "added file"])
def test_an_entry_edited_in_place_is_evicted_not_served(tmp_path: Path, caplog, edit: str):
    """Probe N7: the store counted bytes and files only, so an entry edited in place was
    copied out marked with its content key."""
    store = SequenceStore(tmp_path / "store", max_bytes=1 << 30)
    assert store.put(_fake_sequence(tmp_path / "seq"), KEY)
    entry = store.entry(KEY)
    assert entry is not None
    if edit == "same size":
        (entry / "groundtruth.txt").write_text("1.0 5 0 0 0 0 0 1\n")
    else:  # the same bytes and file count as before: one byte moved to a new file
        data = (entry / "groundtruth.txt").read_bytes()
        (entry / "groundtruth.txt").write_bytes(data[:-1])
        (entry / "rgb" / "x").write_bytes(b"\n")
    with caplog.at_level(logging.WARNING, logger="depotbench.store"):
        assert not store.fetch(KEY, tmp_path / "copy")
    assert not (tmp_path / "copy").exists()
    assert not store.has(KEY) and not entry.exists()
    warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and str(entry) in warnings[0].getMessage()
    # Stored again from a good sequence, it is served again.
    assert store.put(tmp_path / "seq", KEY)
    assert store.fetch(KEY, tmp_path / "copy")
    assert (tmp_path / "copy" / "groundtruth.txt").read_text() == "1.0 0 0 0 0 0 0 1\n"


# -- N10, N24: a suite folder's index.json ------------------------------------------------------


def _suite_folder(tmp_path: Path) -> tuple[Path, Path]:
    folder = tmp_path / "suite"
    with StagedOutput(folder, OutputKind.SUITE) as out:
        out.commit()
    spec = tmp_path / "sweep.yaml"
    spec.write_text("sweep: s\nsequences: [suite]\nstrategies: [none]\n")
    return folder, spec


@pytest.mark.parametrize("kind", ["fifo", "oversized", "deep"])
def test_a_hostile_suite_index_is_one_line_naming_it(tmp_path: Path, capsys, kind: str):
    folder, spec = _suite_folder(tmp_path)
    index = folder / "index.json"
    if kind == "fifo":
        os.mkfifo(index)
    elif kind == "oversized":
        with index.open("wb") as handle:  # sparse: no disk, but read whole it costs the memory
            handle.truncate(257 << 20)
    else:
        index.write_text("[" * 200_000 + "]" * 200_000)
    with _within(20):
        code = main(["validate", str(spec)])
    assert code == 2
    expected = {"fifo": "not a regular file", "oversized": "limit", "deep": "nested too deeply"}[kind]
    _one_line(capsys.readouterr().err, str(index), expected)


# -- N15: YAML's duplicate-key check -----------------------------------------------------------


def test_a_mapping_of_many_keys_is_checked_for_duplicates_in_linear_time():
    """Probe N15: the check scanned a list, so 80,000 keys (0.87 MB of YAML) cost 48 s.
    The mapping node is built here, so that only the check is timed, not the parser."""
    import yaml
    from depotbench.scenes.schema import _StrictLoader

    def scalar(tag: str, value: str) -> yaml.ScalarNode:
        return yaml.ScalarNode(f"tag:yaml.org,2002:{tag}", value)

    pairs = [(scalar("str", f"k{i}"), scalar("int", "0")) for i in range(80_000)]
    loader = _StrictLoader("")
    start = time.perf_counter()
    mapping = loader.construct_mapping(yaml.MappingNode("tag:yaml.org,2002:map", pairs))
    assert len(mapping) == 80_000
    with pytest.raises(yaml.constructor.ConstructorError, match="'k7' appears twice"):
        loader.construct_mapping(yaml.MappingNode("tag:yaml.org,2002:map", [*pairs, pairs[7]]))
    assert time.perf_counter() - start < 5  # 0.3 s with a set; the list's scan took minutes


def test_unhashable_keys_are_still_refused_in_one_line(tmp_path: Path):
    path = tmp_path / "odd.yaml"
    path.write_text("? [a, b]\n: 1\n")
    with pytest.raises(SpecError):
        read_yaml(path)


# -- N18: the stage cache -----------------------------------------------------------------------


def _features_entry() -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, xy=np.arange(4000, dtype=np.float32).reshape(-1, 2), extract_ms=np.ones(3))
    return buffer.getvalue()


@pytest.mark.parametrize("damage", ["truncated", "flipped block", "flipped byte"])
def test_a_damaged_stage_entry_is_a_miss_and_recomputed(tmp_path: Path, damage: str):
    """Probe N18: a truncated or flipped entry raised zipfile.BadZipFile on every run."""
    from depotbench.eval.run.stages import _load

    cache = StageCache(tmp_path / "stages", max_bytes=1 << 30)
    key = content_hash("features", 1)
    data = _features_entry()
    cache.put("features", key, data)
    path = tmp_path / "stages" / "features" / key
    stored = bytearray(path.read_bytes())
    if damage == "truncated":
        stored = stored[: len(stored) // 2]
    elif damage == "flipped block":
        middle = len(stored) // 2
        stored[middle : middle + 512] = bytes(b ^ 0xFF for b in stored[middle : middle + 512])
    else:  # inside the array's bytes: the zip's CRC is never checked by np.load
        stored[len(stored) // 3] ^= 0x01
    path.write_bytes(bytes(stored))
    assert _load(cache.get("features", key)) is None  # a miss, so the stage is computed again
    cache.put("features", key, data)
    loaded = _load(cache.get("features", key))
    assert loaded is not None
    assert np.array_equal(loaded["xy"], np.arange(4000, dtype=np.float32).reshape(-1, 2))


@pytest.mark.parametrize(
    "damage", [zipfile.BadZipFile("bad"), EOFError("short"), __import__("zlib").error("crc")]
)
def test_every_decoding_failure_of_an_entry_means_recompute(damage: Exception, monkeypatch):
    from depotbench.eval.run import stages

    def broken(*args, **kwargs):
        raise damage

    monkeypatch.setattr(stages.np, "load", broken)
    assert stages._load(b"PK\x03\x04") is None


# -- N26, N31: the cache variables and `cache info|clear` --------------------------------------


@pytest.fixture
def clean_env(tmp_path: Path, monkeypatch) -> Path:
    for variable in VARIABLES:
        monkeypatch.delenv(variable, raising=False)
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    return home


@pytest.mark.parametrize(
    ("variable", "value"),
    [
        (ROOT_VARIABLE, "~nosuchuser-depotbench/x"),
        ("DEPOTBENCH_CACHE_STAGES_MAX_BYTES", "9" * 400),
        ("DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES", "1e5"),
        ("DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES", "9" * 30 + "T"),
    ],
)
def test_a_bad_cache_variable_is_one_line(clean_env, monkeypatch, capsys, variable: str, value: str):
    monkeypatch.setenv(variable, value)
    assert main(["cache", "info"]) == 2
    _one_line(capsys.readouterr().err, variable)
    with pytest.raises(InputError, match=variable):
        StageCache.from_env()


def test_a_cache_root_that_is_a_file_is_shown_and_cleared_alike(clean_env, tmp_path, monkeypatch, capsys):
    """Probe N31: ``info`` warned, then failed rc 2; ``clear --stage`` failed while ``clear
    --sequences`` said "removed 0"."""
    (tmp_path / "file").write_text("mine\n")
    monkeypatch.setenv(ROOT_VARIABLE, str(tmp_path / "file"))
    assert main(["cache", "info"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and f"cache root: {tmp_path / 'file'}" in out
    for name in CACHES:
        assert f"{name}: " in out
    assert out.count("not a folder") == len(CACHES), out
    codes = {}
    for flag in ("--stage", "--sequences", "--vocabulary"):
        codes[flag] = main(["cache", "clear", flag])
        out, err = capsys.readouterr()
        assert err == "" and "not a folder" in out and "removed" not in out, (flag, out, err)
    assert set(codes.values()) == {0}
    assert (tmp_path / "file").read_text() == "mine\n"


# -- N20, N25: what rows and checks read of a sequence ------------------------------------------


def test_a_path_is_stored_as_text_and_read_back_losslessly():
    from depotbench.core.path_text import path_text, text_path

    for raw in (b"/d/seq", b"/d/s\xffq", b"/d/a\\x41b", b"/d/\xc3\xa9t\xe9", b"/d/x\\", "/d/é".encode()):
        text = path_text(os.fsdecode(raw))
        text.encode("utf-8")  # what SQLite, JSON and HTML need
        assert os.fsencode(text_path(text)) == raw
    assert path_text("/d/walking-0001") == "/d/walking-0001"  # rows already stored keep their text


def test_a_sequence_folder_whose_name_is_not_utf8_is_swept_and_reported(tmp_path: Path, capsys):
    """Probe N20: the row insert died with UnicodeEncodeError."""
    import sqlite3

    from depotbench.core.path_text import text_path

    from tests.sequences import write_sequence

    folder = Path(os.fsdecode(bytes(tmp_path) + b"/seq\xff"))
    write_sequence(folder, n=3)
    (tmp_path / "x.yaml").write_text("sweep: x\nsequences: ['seq*']\nstrategies: [none]\n")
    assert main(["sweep", str(tmp_path / "x.yaml"), "-o", str(tmp_path / "sw")]) == 0, capsys.readouterr().err
    with contextlib.closing(sqlite3.connect(tmp_path / "sw" / "results.sqlite")) as db:
        (stored,) = db.execute("SELECT sequence FROM runs").fetchone()
    assert (tmp_path / "sw" / text_path(stored)).resolve() == folder.resolve() or text_path(stored) == folder


@pytest.mark.slow
def test_sweeps_of_a_folder_whose_name_is_not_utf8_are_compared_into_a_page(tmp_path: Path, capsys):
    """Probe N20: ``compare --html`` died with UnicodeEncodeError too."""
    from tests.sequences import write_sequence

    write_sequence(Path(os.fsdecode(bytes(tmp_path) + b"/seq\xff")), n=3)
    for name, strategy in (("a", "none"), ("b", "box_rule")):
        spec = f"sweep: {name}\nsequences: ['seq*']\nstrategies: [{strategy}]\n"
        (tmp_path / f"{name}.yaml").write_text(spec)
        assert main(["sweep", str(tmp_path / f"{name}.yaml"), "-o", str(tmp_path / name)]) == 0
    compared = ["compare", str(tmp_path / "a"), str(tmp_path / "b"), "--html", str(tmp_path / "c.html")]
    assert main(compared) == 0, capsys.readouterr().err
    assert (tmp_path / "c.html").read_text(encoding="utf-8").endswith("</html>\n")  # whole


def test_tags_that_are_not_text_are_one_line_naming_the_meta_file(tmp_path: Path, capsys):
    """Probe N25: ``check`` with ``tags:`` died with TypeError: unhashable type."""
    import json

    from tests.sequences import write_sequence

    write_sequence(tmp_path / "seq", n=3)
    meta_path = tmp_path / "seq" / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["scenario"]["tags"] = [["smoke"], 3]
    meta_path.write_text(json.dumps(meta))
    gate = tmp_path / "g.yaml"
    gate.write_text(
        "gates: g\nrun:\n  sequences: [seq]\n  strategies: [none]\nchecks:\n"
        "  - name: tagged\n    tags: [smoke]\n    budgets: {lost_fraction: {max: 1}}\n"
    )
    assert main(["check", str(gate), "-o", str(tmp_path / "chk")]) == 2
    _one_line(capsys.readouterr().err, "meta.json", "tags")


def test_a_glob_skips_the_sweeps_own_output_folder(tmp_path: Path, capsys):
    """Probe N28: ``sequences: ['*']`` matched the output folder, made (and marked) before the
    glob was expanded: ``sw/rgb.txt: file is missing``."""
    import sqlite3

    from tests.sequences import write_sequence

    write_sequence(tmp_path / "seqa", n=3)
    (tmp_path / "x.yaml").write_text("sweep: x\nsequences: ['*']\nstrategies: [none]\n")
    for _ in range(2):  # and again, resumed: the folder now holds a finished sweep
        assert main(["sweep", str(tmp_path / "x.yaml"), "-o", str(tmp_path / "sw")]) == 0, capsys.readouterr()
    with contextlib.closing(sqlite3.connect(tmp_path / "sw" / "results.sqlite")) as db:
        assert [row[0] for row in db.execute("SELECT sequence FROM runs")] == [str(tmp_path / "seqa")]


@pytest.mark.slow
def test_an_unusable_cache_is_warned_once_by_the_sweep_not_by_each_worker(tmp_path: Path, capfd, monkeypatch):
    """Probe M1: with two workers, 11-14 copies of the warning, the workers' without the
    ``depotbench sweep: warning:`` prefix."""
    from tests.sequences import write_sequence

    for i in range(3):
        write_sequence(tmp_path / f"seq{i}", n=3, seed=i)  # distinct: a sequence twice is refused
    (tmp_path / "blocker").write_text("")
    monkeypatch.setenv(ROOT_VARIABLE, str(tmp_path / "blocker"))  # a file where the cache should be
    (tmp_path / "x.yaml").write_text("sweep: x\nsequences: ['seq*']\nstrategies: [none, box_rule]\n")
    assert main(["sweep", str(tmp_path / "x.yaml"), "-o", str(tmp_path / "sw"), "--workers", "2"]) == 0
    err = capfd.readouterr().err
    mentions = [line for line in err.splitlines() if "stage cache" in line]
    assert len(mentions) == 1 and mentions[0].startswith("depotbench sweep: warning: "), err


def test_a_fifo_map_is_refused_by_the_report_without_blocking(tmp_path: Path):
    from depotbench.core.errors import FileError
    from depotbench.eval.report.maps import check_map_ply

    os.mkfifo(tmp_path / "map.ply")
    with _within(2), pytest.raises(FileError, match="not a regular file"):
        check_map_ply(tmp_path / "map.ply")


@pytest.mark.parametrize("kind", ["fifo", "truncated"])
def test_a_hostile_flow_file_is_refused_without_blocking(tmp_path: Path, kind: str):
    from depotbench.core.errors import FileError
    from depotbench.sim.sequence import Sequence

    from tests.sequences import write_sequence

    write_sequence(tmp_path / "seq", n=2)
    flows = sorted((tmp_path / "seq" / "gt" / "flow").iterdir())
    if kind == "fifo":
        flows[0].unlink()
        os.mkfifo(flows[0])
    else:
        flows[0].write_bytes(flows[0].read_bytes()[:-40])
    with _within(2), pytest.raises(FileError, match="flow"):
        Sequence.open(tmp_path / "seq").flow(0)
