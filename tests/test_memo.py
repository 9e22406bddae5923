"""World building's kept meshes and textures (sim/memo.py): exact, or not kept at all."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.cli.main import main
from depotbench.sim import world
from depotbench.sim.figures import Look
from depotbench.sim.memo import MEMOS, Memo, content_key, kept

from tests.conftest import REPO
from tests.sequences import tree_differences


def test_equal_content_is_one_key_and_any_difference_another():
    look = Look.draw(np.random.default_rng(3))
    assert content_key(1.0, look, {"a": np.arange(3.0)}) == content_key(1.0, look, {"a": np.arange(3.0)})
    different = [
        content_key(0.1),
        content_key(np.nextafter(0.1, 1.0)),  # one bit of the float
        content_key(-0.0),
        content_key(0.0),
        content_key(np.zeros(4)),
        content_key(np.zeros((2, 2))),  # the same bytes in another shape
        content_key(np.zeros(4, np.float32), np.zeros(4, np.float32)),  # the same 32 bytes
        content_key((1, 2)),
        content_key([1, 2]),
        content_key(1),
        content_key(True),
        content_key("1"),
        content_key(("ab", "c")),
        content_key(("a", "bc")),
        content_key(look),
        content_key(Look.draw(np.random.default_rng(4))),
    ]
    assert len(set(different)) == len(different)
    with pytest.raises(TypeError, match="object has no content digest"):
        content_key(object())


def test_a_kept_result_is_read_only_and_the_oldest_entry_goes_first():
    calls = []

    @kept("test squares", 2)
    def squares(n: int) -> np.ndarray:
        calls.append(n)
        return np.arange(n) ** 2

    first = squares(3)
    assert squares(3) is first and calls == [3]
    with pytest.raises(ValueError, match="read-only"):
        first[0] = 7
    squares(4)
    squares(3)  # used last: 4 is now the oldest
    squares(5)
    assert calls == [3, 4, 5]
    squares(3)
    squares(4)
    assert calls == [3, 4, 5, 4]
    assert (MEMOS["test squares"].hits, MEMOS["test squares"].misses) == (3, 4)
    bounded = Memo("bounded", 1)
    bounded.put(b"a", 1)
    bounded.put(b"b", 2)
    assert len(bounded) == 1 and bounded.get(b"a") is None and bounded.get(b"b") == 2


def test_kept_textures_leave_the_stream_where_drawing_them_leaves_it():
    """The texture generator goes on after a hit exactly as after the draws themselves."""
    from depotbench.sim import actor_registry

    clothing = [("plain", actor_registry.get("person"))]
    looks = [Look.draw(np.random.default_rng(1))]
    world.TEXTURES.clear()
    drawn_rng, kept_rng = np.random.default_rng(11), np.random.default_rng(11)
    drawn = world._material_images(drawn_rng, clothing, looks)
    kept_images = world._material_images(kept_rng, clothing, looks)
    assert world.TEXTURES.hits == 1 and world.TEXTURES.misses == 1
    assert kept_images.keys() == drawn.keys()
    assert all(np.array_equal(kept_images[m][1], drawn[m][1]) for m in drawn)
    assert kept_rng.bit_generator.state == drawn_rng.bit_generator.state
    assert kept_rng.integers(1 << 62) == drawn_rng.integers(1 << 62)
    assert kept_images is not drawn  # each caller its own dictionary of the same images


@pytest.mark.render
def test_a_world_built_from_kept_pieces_is_the_bytes_of_one_built_in_a_fresh_process(tmp_path: Path):
    """A person and a cat (both kinds of carved meshes) and their textures: the second
    sequence of this process takes every one of them from the memos."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(
        json.dumps(
            {
                "name": "tiny",
                "image": {"width": 96, "height": 72},
                "intrinsics": {"fx": 78.75},
                "seed": 5,
                "frames": 2,
                "actors": [{"kind": "person"}, {"kind": "cat", "speed_mps": 0.6}],
            }
        )
    )
    for memo in MEMOS.values():
        memo.clear()
    assert main(["generate", str(spec), "-o", str(tmp_path / "built")]) == 0
    assert main(["generate", str(spec), "-o", str(tmp_path / "kept")]) == 0
    hits = {name: MEMOS[name].hits for name in ("person meshes", "animal meshes", "textures")}
    assert hits == {"person meshes": 1, "animal meshes": 1, "textures": 1}
    fresh = subprocess.run(
        [sys.executable, "-m", "depotbench.eval.cli", "generate", str(spec), "-o", str(tmp_path / "fresh")],
        cwd=REPO,
        capture_output=True,
        text=True,
        env=os.environ | {"MUJOCO_GL": "egl"},
    )
    assert fresh.returncode == 0, fresh.stderr
    skip = ("meta.json",)  # its timings and host
    assert tree_differences(tmp_path / "fresh", tmp_path / "kept", skip=skip) == []
    assert tree_differences(tmp_path / "fresh", tmp_path / "built", skip=skip) == []
    meta = [json.loads((tmp_path / name / "meta.json").read_text()) for name in ("fresh", "kept")]
    assert meta[0] == meta[1]
