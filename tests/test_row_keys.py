"""A row's key: it changes with every input a row depends on and with nothing else.

The keys are the engine's own (``engine.expand`` over a sweep spec: ``job_key`` of the
sequence fingerprint and ``tracker_identity``), on a 2-frame 64x48 sequence, so each
example costs a few milliseconds. O3 of ``reliability-probe-2.md``: a command's script and
config file were not in the key, so an edited script resumed the old rows."""

from __future__ import annotations

import json
import os
import random
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from unittest import mock

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.run import harness
from depotbench.eval.run.harness import command_files, tracker_fingerprint, tracker_identity
from depotbench.eval.sweep.engine import expand
from depotbench.eval.sweep.spec import load_sweep
from depotbench.eval.trackers.registry import TrackerConfig
from depotbench.sim.sequence import Sequence
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.sequences import write_sequence


class World:
    """A sweep spec with an external tracker whose command names a script, a config file
    (``--config PATH``), an ``--opt=PATH`` file and a folder, over one sequence kept inside
    the sweep folder."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.sweep = root / "sweep"
        self.sequence = self.sweep / "seq"
        write_sequence(self.sequence, n=2, with_flow=False)
        self.script, self.config, self.option = root / "prog.py", root / "conf.yaml", root / "opt.txt"
        self.folder, self.template = root / "data", root / "settings.j2"
        self.script.write_text("print('v1')\n")
        self.config.write_text("window: 3\n")
        self.option.write_text("fast\n")
        self.folder.mkdir()
        (self.folder / "inside.txt").write_text("1\n")
        self.template.write_text("window: {{ 1 }}\n")
        self.spec: dict = {
            "sweep": "keys",
            "sequences": [str(self.sequence)],
            "trackers": [
                {
                    "name": "mine",
                    "command": f"{sys.executable} {self.script} --config {self.config} "
                    f"--opt={self.option} {self.folder} {{sequence}} {{trajectory}} {{window}}",
                    "parameters": {"window": 3},
                    "settings": str(self.template),
                    "env": {"A": "1"},
                }
            ],
            "detectors": [
                {
                    "detector": "groundtruth",
                    "settings": {"min_visible_pixels": 20},
                    "faults": {"miss": 0.3, "latency": 1},
                }
            ],
            "strategies": ["mask"],  # and the none run the engine adds as rho's reference
            "thresholds": {"mask": {"box_dilation_px": {"grid": [4]}}},
        }

    def keys(self, order: Callable[[list], list] = lambda keys: keys) -> list[str]:
        """The sweep's job keys; ``order`` reorders each mapping's keys in the spec file."""

        def reordered(value):
            if isinstance(value, dict):
                return {k: reordered(value[k]) for k in order(list(value))}
            return [reordered(v) for v in value] if isinstance(value, list) else value

        spec_path = self.root / "spec.yaml"  # JSON is YAML, and 20x faster to write
        spec_path.write_text(json.dumps(reordered(self.spec)))
        jobs = expand(load_sweep(spec_path), spec_path, [(self.sequence, "f")], anchor=self.sweep)
        return [job.key for job in jobs]


def _flip_last_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF
    path.write_bytes(bytes(data))


def _binary_files(world: World) -> list[Path]:
    return [p for p in Sequence.open(world.sequence).files() if p.suffix == ".png"]


CHANGES: dict[str, Callable[[World, random.Random], None]] = {
    "sequence bytes": lambda w, r: _flip_last_byte(r.choice(_binary_files(w))),
    "detector fault": lambda w, r: w.spec["detectors"][0]["faults"].update(miss=r.choice([0.1, 0.5, 0.9])),
    "detector latency": lambda w, r: w.spec["detectors"][0]["faults"].update(latency=r.randint(2, 9)),
    "detector setting": lambda w, r: w.spec["detectors"][0]["settings"].update(
        min_visible_pixels=r.randint(21, 99)
    ),
    "program script": lambda w, r: w.script.write_text(f"print('v{r.randint(2, 10**9)}')\n"),
    "config file": lambda w, r: w.config.write_text(f"window: {r.randint(4, 10**9)}\n"),
    "--opt= file": lambda w, r: w.option.write_text(f"slow{r.randint(0, 10**9)}\n"),
    "parameter": lambda w, r: w.spec["trackers"][0]["parameters"].update(window=r.randint(4, 99)),
    "settings template": lambda w, r: w.template.write_text(f"window: {{{{ {r.randint(2, 10**9)} }}}}\n"),
    "environment": lambda w, r: w.spec["trackers"][0]["env"].update(A=str(r.randint(2, 99))),
    "threshold": lambda w, r: w.spec["thresholds"]["mask"]["box_dilation_px"].update(grid=[r.randint(5, 40)]),
}
"""Every input a row depends on, each changed at random."""


def _mtimes(world: World, r: random.Random) -> None:
    for path in [world.script, world.config, world.option, world.template, *world.sequence.rglob("*")]:
        stamp = r.randint(10**8, 2 * 10**9)
        os.utime(path, (stamp, stamp))


def _move_sweep(world: World, r: random.Random) -> None:
    """The whole sweep folder moved (its sequence inside it): rows name it relative."""
    moved = world.root / f"moved-{r.randint(0, 10**9)}"
    shutil.move(world.sweep, moved)
    world.sweep, world.sequence = moved, moved / "seq"
    world.spec["sequences"] = [str(world.sequence)]


def _rename_sequence(world: World, r: random.Random) -> None:
    """The sequence folder renamed, or moved out of the sweep folder: the same files."""
    where = r.choice([world.sweep, world.root])
    renamed = where / f"renamed-{r.randint(0, 10**9)}"
    shutil.move(world.sequence, renamed)
    world.sequence = renamed
    world.spec["sequences"] = [str(renamed)]


def _folder_content(world: World, r: random.Random) -> None:
    """A folder the command names is keyed by its name only (its content is the program's
    business: a data set may be any size)."""
    (world.folder / "inside.txt").write_text(f"{r.randint(2, 10**9)}\n")


SAME: dict[str, Callable[[World, random.Random], None]] = {
    "mtime": _mtimes,
    "sweep folder moved": _move_sweep,
    "sequence folder renamed or moved": _rename_sequence,
    "content of a named folder": _folder_content,
}
"""What a row does not depend on."""


def _world() -> World:
    return World(Path(tempfile.mkdtemp(prefix="depotbench-keys-")))


@pytest.mark.parametrize("change", sorted(CHANGES))
@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1))
def test_a_change_to_any_input_a_row_depends_on_changes_every_key(change: str, seed: int):
    world = _world()
    try:
        before = world.keys()
        CHANGES[change](world, random.Random(seed))
        after = world.keys()
        # the jobs are (none, mask): a threshold of mask is no input of the none run
        changed = [b != a for b, a in zip(before, after, strict=True)]
        assert changed == ([False, True] if change == "threshold" else [True, True]), change
    finally:
        shutil.rmtree(world.root)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(change=st.sampled_from(sorted(SAME)), seed=st.integers(0, 2**32 - 1), order_seed=st.integers(0, 99))
def test_a_change_to_nothing_a_row_depends_on_keeps_every_key(change: str, seed: int, order_seed: int):
    """mtime, the sweep folder's place, the sequence folder's name and place, a named folder's
    content, and the order of the spec's
    YAML keys (shuffled in every mapping)."""
    world = _world()
    try:
        before = world.keys()
        SAME[change](world, random.Random(seed))
        shuffle = random.Random(order_seed)
        assert world.keys(lambda keys: shuffle.sample(keys, len(keys))) == before, change
    finally:
        shutil.rmtree(world.root)


def test_the_bench_version_changes_every_key(tmp_path: Path):
    world = World(tmp_path)
    before = world.keys()
    with mock.patch.object(harness, "code_version", lambda: "99.0.0"):
        assert not set(world.keys()) & set(before)


def test_o3_an_interpreters_script_and_its_config_file_are_in_the_key(tmp_path: Path, monkeypatch):
    """O3: ``python3 /abs/prog.py --config conf.yaml``: an edited script or config file is a
    new tracker identity (and fingerprint), so its rows are new rows. Relative words resolve
    from the folder the bench was started in, as the program word does."""
    monkeypatch.chdir(tmp_path)
    script, config = tmp_path / "prog.py", tmp_path / "conf.yaml"
    script.write_text("print(1)\n")
    config.write_text("a: 1\n")
    tracker = TrackerConfig("cmd", f"{sys.executable} {script} --config conf.yaml {{sequence}}", name="mine")
    first = tracker_identity(tracker)
    assert [word for word, _ in command_files(tracker.command or "")] == [str(script), "conf.yaml"]
    script.write_text("print(2)\n")
    second = tracker_identity(tracker)
    config.write_text("a: 2\n")
    third = tracker_identity(tracker)
    assert len({first, second, third}) == 3
    assert len({tracker_fingerprint(i) for i in (first, second, third)}) == 3
    assert tracker_identity(tracker) == third  # and nothing else moves it
    # a parameter is a configuration of one program version, not another version
    swept = replace(tracker, parameters=(("window", "5"),))
    assert tracker_fingerprint(tracker_identity(swept)) == tracker_fingerprint(third)
    assert tracker_identity(swept) != third


def test_a_command_naming_more_than_the_bound_is_refused_in_one_line(tmp_path: Path, monkeypatch):
    big = tmp_path / "weights.bin"
    big.write_bytes(b"\0" * 2048)
    monkeypatch.setattr(harness, "COMMAND_FILES_MAX_BYTES", 1024)
    tracker = TrackerConfig("cmd", f"{sys.executable} --model={big} {{sequence}}", name="mine")
    with pytest.raises(InputError) as refused:
        tracker_identity(tracker)
    assert (
        "\n" not in str(refused.value)
        and "tracker mine" in str(refused.value)
        and "2048" in str(refused.value)
    )


@pytest.mark.slow  # three sweeps, each starting its program: 5 s
def test_a_sweep_keeps_rows_of_an_older_program_apart_and_prune_stale_removes_them(tmp_path: Path, caplog):
    """(Issue 50, item 2.) Swept again after its script changed, a folder keeps the old rows
    out of the new run's rows and summary, says so per version, and ``--prune-stale`` removes
    them, naming each version before it goes."""
    import logging

    from depotbench.eval.cli.main import main
    from depotbench.eval.sweep.store import ResultStore

    def fingerprints() -> list[str | None]:
        with ResultStore(out / "results.sqlite", readonly=True) as store:
            return [r.tracker_fingerprint for r in store.records()]

    write_sequence(tmp_path / "seq", n=2, with_flow=False)
    script = tmp_path / "prog.py"
    script.write_text("raise SystemExit(3)\n")  # a failed row is a row: no tracking needed
    command = f"{sys.executable} {script} {{sequence}} {{trajectory}}"
    spec = tmp_path / "spec.yaml"
    spec.write_text(
        json.dumps(
            {
                "sweep": "stale",
                "sequences": [str(tmp_path / "seq")],
                "trackers": [{"name": "mine", "command": command}],
                "detectors": ["none"],
            }
        )
    )
    out = tmp_path / "out"
    sweep = ["sweep", str(spec), "-o", str(out), "--workers", "1"]
    assert main(sweep) == 0
    (old,) = fingerprints()
    script.write_text("raise SystemExit(4)\n")
    caplog.set_level(logging.INFO)
    assert main(sweep) == 0
    (new,) = set(fingerprints()) - {old}
    kept = f"1 row of tracker mine fingerprint {old} (now {new})"
    assert [m for r in caplog.records if "kept apart" in (m := r.getMessage())] == [
        f"{kept} kept apart, not reused; --prune-stale removes them"
    ]
    summary = json.loads((out / "summary.json").read_text())
    assert [c["runs"] for c in summary["configurations"]] == [1]
    with ResultStore(out / "results.sqlite", readonly=True) as store:  # as report reads it
        assert [r.tracker_fingerprint for r in store.current_records()] == [new]
    caplog.clear()
    assert main([*sweep, "--prune-stale"]) == 0
    removed = [m for r in caplog.records if "prune" in (m := r.getMessage())]
    assert removed == [f"--prune-stale: removing {kept}"]
    assert fingerprints() == [new]
