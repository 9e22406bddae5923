"""One cache root read the same way by every cache, and ``depotbench cache info|clear``
(issue 39 point 5): sizes counted on the disk, and clearing that deletes only what the
caches wrote, beside a bench that is using them."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pytest
from depotbench.core.cache_home import CACHES, RETIRED, ROOT_VARIABLE, cache_folder
from depotbench.core.errors import InputError
from depotbench.core.output import MARKER_NAME, OutputKind, OutputLock, StagedOutput
from depotbench.eval.cli.cache import HANDLING, bytes_text
from depotbench.eval.cli.main import main
from depotbench.eval.run.cache import StageCache, content_hash
from depotbench.eval.trackers.vocabulary import VocabularySpec, cached_name, default_vocabulary
from depotbench.scenes.store import SequenceStore

VARIABLES = (
    ROOT_VARIABLE,
    "XDG_CACHE_HOME",
    *RETIRED,
    *(c.variable for c in CACHES.values()),
    *(c.bound_variable for c in CACHES.values() if c.bound_variable),
)


@pytest.fixture(autouse=True)
def home(tmp_path: Path, monkeypatch) -> Path:
    """No cache variable set, and a home of the test's own."""
    for variable in VARIABLES:
        monkeypatch.delenv(variable, raising=False)
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    return home


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["cache", *args])
    out, err = capsys.readouterr()
    return code, out, err


# -- one root, read the same way everywhere ----------------------------------------------------


LAYOUTS = [
    ({}, {name: "{home}/.cache/depotbench/" + name for name in CACHES}),
    ({"XDG_CACHE_HOME": "{tmp}/xdg"}, {name: "{tmp}/xdg/depotbench/" + name for name in CACHES}),
    ({"XDG_CACHE_HOME": "relative/xdg"}, {name: "{home}/.cache/depotbench/" + name for name in CACHES}),
    ({ROOT_VARIABLE: "on"}, {name: "{home}/.cache/depotbench/" + name for name in CACHES}),
    ({ROOT_VARIABLE: "{tmp}/root"}, {name: "{tmp}/root/" + name for name in CACHES}),
    ({ROOT_VARIABLE: "~/elsewhere"}, {name: "{home}/elsewhere/" + name for name in CACHES}),
    ({ROOT_VARIABLE: "OFF"}, {name: None for name in CACHES}),
    ({ROOT_VARIABLE: "0"}, {name: None for name in CACHES}),
    (  # off is a master switch: no cache variable reopens one
        {ROOT_VARIABLE: "off", "DEPOTBENCH_CACHE_VOCABULARY": "on", "DEPOTBENCH_CACHE_STAGES": "{tmp}/s"},
        {name: None for name in CACHES},
    ),
    (
        {ROOT_VARIABLE: "{tmp}/root", "DEPOTBENCH_CACHE_SEQUENCES": "false"},
        {"stages": "{tmp}/root/stages", "sequences": None, "vocabulary": "{tmp}/root/vocabulary"},
    ),
    (
        {ROOT_VARIABLE: "{tmp}/root", "DEPOTBENCH_CACHE_STAGES": "on"},
        {name: "{tmp}/root/" + name for name in CACHES},
    ),
    (
        {"DEPOTBENCH_CACHE_STAGES": "{tmp}/fast", "DEPOTBENCH_CACHE_VOCABULARY": "no"},
        {
            "stages": "{tmp}/fast",
            "sequences": "{home}/.cache/depotbench/sequences",
            "vocabulary": None,
        },
    ),
]


@pytest.mark.parametrize(("settings", "expected"), LAYOUTS)
def test_every_cache_is_found_where_the_variables_say(
    settings, expected, tmp_path: Path, home: Path, monkeypatch
):
    def fill(text: str | None) -> Path | None:
        return None if text is None else Path(text.format(home=home, tmp=tmp_path))

    for variable, value in settings.items():
        monkeypatch.setenv(variable, value.format(home=home, tmp=tmp_path))
    found = {name: cache_folder(name) for name in CACHES}
    assert found == {name: fill(text) for name, text in expected.items()}
    # Each cache's own reader asks the same question.
    stages = StageCache.from_env()
    assert (stages.root if stages else None) == found["stages"]
    store = SequenceStore.from_env()
    assert (store.root if store else None) == found["sequences"]
    if found["vocabulary"] is not None:  # a vocabulary there is the one handed out
        built = found["vocabulary"] / cached_name(VocabularySpec())
        built.parent.mkdir(parents=True)
        built.write_text("1 1 0 0")
        assert default_vocabulary(progress=False) == built


BAD = [
    (ROOT_VARIABLE, "cache"),  # relative: it would land wherever a command runs
    (ROOT_VARIABLE, "of"),
    ("DEPOTBENCH_CACHE_STAGES", "./stages"),
    ("DEPOTBENCH_CACHE_VOCABULARY", "none"),
    ("DEPOTBENCH_CACHE_STAGES_MAX_BYTES", "lots"),
    ("DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES", "-1"),
    *((old, "/tmp/anywhere") for old in RETIRED),
]


@pytest.mark.parametrize(("variable", "value"), BAD)
def test_a_bad_or_retired_variable_is_one_line_naming_it(variable: str, value: str, capsys, monkeypatch):
    monkeypatch.setenv(variable, value)
    for args in (["info"], ["info", "--json"], ["clear"]):
        code, out, err = _cli(capsys, *args)
        assert code == 2 and out == "", (args, out)
        assert err.count("\n") == 1 and f"{variable}={value!r}" in err and "Traceback" not in err, err
    if variable in RETIRED:
        assert RETIRED[variable] in err  # says what replaced it
    with pytest.raises(InputError, match=variable):
        StageCache.from_env() if "SEQUENCES" not in variable else SequenceStore.from_env()


# -- info ----------------------------------------------------------------------------------


def _fake_sequence(root: Path, key: str, size: int) -> Path:
    """A folder marked as a complete sequence of ``key``: the store copies any files."""
    with StagedOutput(root, OutputKind.SEQUENCE, content_key=key) as out:
        (out.path / "rgb").mkdir()
        (out.path / "rgb" / "frame.png").write_bytes(os.urandom(size))
        (out.path / "meta.json").write_text("{}\n")
        out.commit()
    return root


def _fill(root: Path, tmp_path: Path) -> dict[str, list[Path]]:
    """Entries in every cache under ``root``, written by the caches themselves; returns
    the path of each entry (a sequence's folder)."""
    stages = StageCache(root / "stages")
    for i in range(3):
        stages.put(("features", "flow", "detections")[i], content_hash(i), os.urandom(1000 * (i + 1)))
    store = SequenceStore(root / "sequences")
    keys = [f"sha256:{i:064x}" for i in (1, 2)]
    for i, key in enumerate(keys):
        assert store.put(_fake_sequence(tmp_path / f"source{i}", key, 5000 * (i + 1)), key)
    vocabulary = root / "vocabulary"
    vocabulary.mkdir(exist_ok=True)
    names = [cached_name(VocabularySpec()), cached_name(VocabularySpec(branching=4, levels=2))]
    for i, name in enumerate(names):
        (vocabulary / name).write_bytes(os.urandom(700 * (i + 1)))
    return {
        "stages": sorted(p for p in (root / "stages").rglob("*") if p.is_file()),
        "sequences": [store.entry(key) for key in keys],
        "vocabulary": [vocabulary / name for name in names],
    }


def _disk_bytes(path: Path) -> int:
    """An entry's bytes as the disk has them (a sequence's files but its marker)."""
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and p.name != MARKER_NAME)


def test_info_counts_what_is_on_the_disk(tmp_path: Path, capsys, monkeypatch):
    root = tmp_path / "root"
    monkeypatch.setenv(ROOT_VARIABLE, str(root))
    monkeypatch.setenv("DEPOTBENCH_CACHE_STAGES_MAX_BYTES", "500M")
    entries = _fill(root, tmp_path)
    assert set(HANDLING) == set(CACHES)
    code, out, _ = _cli(capsys, "info", "--json")
    assert code == 0
    state = json.loads(out)
    assert state["root"] == str(root) and state["root_from"] == f"{ROOT_VARIABLE}={str(root)!r}"
    for name, paths in entries.items():
        cache = state["caches"][name]
        assert cache["location"] == str(root / name) and not cache["off"]
        assert (cache["entries"], cache["bytes"]) == (len(paths), sum(_disk_bytes(p) for p in paths)), name
    assert state["caches"]["stages"]["bound_bytes"] == 500 << 20
    assert state["caches"]["sequences"]["bound_bytes"] == 20 << 30
    assert state["caches"]["vocabulary"]["bound_bytes"] is None
    code, out, _ = _cli(capsys, "info")
    assert code == 0 and f"cache root: {root}" in out
    assert f"  location: {root / 'stages'}" in out
    assert "in 3 entries, bound 500.0 MiB (DEPOTBENCH_CACHE_STAGES_MAX_BYTES)" in out
    assert "in 2 entries, unbounded" in out
    monkeypatch.setenv("DEPOTBENCH_CACHE_SEQUENCES", "off")
    code, out, _ = _cli(capsys, "info")
    assert "sequences: rendered sequences, by content key\n  off (DEPOTBENCH_CACHE_SEQUENCES='off')\n" in out


def test_info_creates_nothing(tmp_path: Path, home: Path, capsys):
    code, out, _ = _cli(capsys, "info")
    assert code == 0 and f"cache root: {home}/.cache/depotbench (~/.cache/depotbench)" in out
    assert not (home / ".cache").exists()


@pytest.mark.parametrize(
    ("size", "text"), [(0, "0 B"), (1023, "1023 B"), (1536, "1.5 KiB"), (3 << 30, "3.0 GiB")]
)
def test_sizes_are_printed_in_units_of_1024(size: int, text: str):
    assert bytes_text(size) == text


# -- clear ---------------------------------------------------------------------------------


def _digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and not p.is_symlink()
    }


def test_clearing_a_root_set_to_a_users_home_deletes_only_cache_entries(
    tmp_path: Path, home: Path, capsys, monkeypatch
):
    """``DEPOTBENCH_CACHE=$HOME`` by mistake: every file of the user's stays."""
    monkeypatch.setenv(ROOT_VARIABLE, str(home))
    mine = {
        "notes.txt": "a",
        "stages/notes.txt": "b",
        "stages/features/README": "c",  # in a stage's folder, named as no entry is
        "stages/features/" + "A" * 32: "d",  # upper case: not a key
        "stages/.git/" + "a" * 32: "e",  # a folder that is no stage
        "stages/my notes/" + "b" * 32: "f",
        "sequences/photos/holiday.png": "g",
        "sequences/" + "c" * 64: "h",  # no PNG level: not an entry
        "vocabulary/orb-notes.txt": "i",
        "vocabulary/orb-k10-L5-mine.txt": "j",
    }
    for name, text in mine.items():
        (home / name).parent.mkdir(parents=True, exist_ok=True)
        (home / name).write_text(text)
    outside = tmp_path / "precious.txt"
    outside.write_text("keep")
    (home / "stages" / "features" / ("d" * 32)).symlink_to(outside)  # named as an entry, a link
    before = _digests(home)
    entries = _fill(home, tmp_path)
    freed = sum(_disk_bytes(p) for paths in entries.values() for p in paths)
    code, out, err = _cli(capsys, "clear")
    assert code == 0 and err == "", err
    assert out.splitlines()[-1] == f"freed {bytes_text(freed)}"
    assert "stages: removed 3 entries" in out and "sequences: removed 2 entries" in out
    assert "vocabulary: removed 2 entries" in out
    assert _digests(home) == before  # the user's files, and nothing else
    assert outside.read_text() == "keep" and (home / "stages" / "features" / ("d" * 32)).is_symlink()


def test_clear_takes_only_the_caches_named(tmp_path: Path, capsys, monkeypatch):
    root = tmp_path / "root"
    monkeypatch.setenv(ROOT_VARIABLE, str(root))
    entries = _fill(root, tmp_path)
    code, out, _ = _cli(capsys, "clear", "--stage", "--vocabulary")
    assert code == 0 and "sequences" not in out
    assert not any(p.exists() for p in entries["stages"] + entries["vocabulary"])
    assert all(p.is_dir() for p in entries["sequences"])
    code, out, _ = _cli(capsys, "clear", "--sequences")
    assert code == 0 and out.startswith("sequences: removed 2 entries")
    assert not any(p.exists() for p in entries["sequences"])
    assert sorted(p.name for p in (root / "sequences").iterdir()) == []  # manifests went too


def test_clearing_beside_a_bench_at_work_spares_its_reader_and_its_writer(
    tmp_path: Path, capsys, monkeypatch
):
    root = tmp_path / "root"
    monkeypatch.setenv(ROOT_VARIABLE, str(root))
    entries = _fill(root, tmp_path)
    reading = entries["stages"][0]
    expected = reading.read_bytes()
    being_written = entries["sequences"][1]
    with reading.open("rb") as reader, OutputLock(being_written):  # another process storing it
        code, out, _ = _cli(capsys, "clear")
        assert reader.read() == expected  # the reader's entry stays whole for it
    assert code == 0 and "sequences: removed 1 entries" in out
    assert "kept 1 being written by another depotbench" in out
    assert being_written.is_dir() and not entries["sequences"][0].exists() and not reading.exists()


def test_caches_switched_off_are_neither_cleared_nor_listed(tmp_path: Path, home: Path, capsys, monkeypatch):
    entries = _fill(home / ".cache" / "depotbench", tmp_path)
    monkeypatch.setenv(ROOT_VARIABLE, "off")
    code, out, _ = _cli(capsys, "clear")
    assert code == 0
    for name in CACHES:
        assert f"{name}: off (DEPOTBENCH_CACHE='off'), nothing to clear" in out
    assert all(p.exists() for paths in entries.values() for p in paths)
    code, out, _ = _cli(capsys, "info", "--json")
    state = json.loads(out)
    assert state["root"] is None
    assert {c["switched_off_by"] for c in state["caches"].values()} == {"DEPOTBENCH_CACHE='off'"}


# -- the vocabulary when the cache is off ----------------------------------------------------


def test_the_vocabulary_is_refused_not_built_when_its_cache_is_off(tmp_path: Path, capsys, monkeypatch):
    """Building one takes minutes, in every process that needs one: off says how to pass it."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(ROOT_VARIABLE, "off")
    code = main(["vocab", "--scenes", "smoke", "--frames", "2", "--branching", "2", "--levels", "1"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "DEPOTBENCH_CACHE='off'" in err and "`depotbench vocab -o FILE` and pass --vocabulary FILE" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["home"] and not any((tmp_path / "home").iterdir())
