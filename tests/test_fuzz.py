"""Every bad input gets one clear line: a fuzz suite over the five kinds of input.

Each case hands the command line a malformed scenario spec, suite, sequence
folder, trajectory or argument list and asserts: exit code 2, exactly one line
on stderr that names the file, field, frame or option, no traceback, nothing
written where the output would go, and the input byte for byte as it was.
Hypothesis adds random corruptions on top of the hand-written cases, and a few
cases run in a child process with a memory cap to show that oversized or
endless inputs are refused before they are read.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.eval.cli.main import main
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from tests.capped import MAX_RSS_MB, peak_rss_mb
from tests.sequences import write_sequence
from tests.test_output import snapshot

FUZZ_EXAMPLES = int(os.environ.get("DEPOTBENCH_FUZZ_EXAMPLES", "150"))
"""Hypothesis examples per property (raise it for a long fuzzing session)."""


@dataclass(frozen=True)
class Case:
    """A malformed input: how to make it in ``tmp``, the command, what the error must name."""

    make: Callable[[Path], None]
    args: tuple[str, ...]
    needle: str


def check_refused(tmp: Path, capfd, case: Case) -> None:
    """Run the case; exit 2, one line naming the thing, nothing written, the input untouched."""
    case.make(tmp)
    before = snapshot(tmp)
    listing = sorted(p.name for p in tmp.rglob("*"))
    args = [a.replace("{tmp}", str(tmp)) for a in case.args]
    with pytest.raises(SystemExit) if args[0] == "__argparse__" else _no_exit():
        code = main(args[1:] if args[0] == "__argparse__" else args)
        assert code == 2, f"exit {code} for {args}"
    err = capfd.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, f"{len(lines)} lines for {args}:\n{err}"
    assert "Traceback" not in err
    needle = case.needle.replace("{tmp}", str(tmp))
    assert needle in lines[0], f"{needle!r} not in {lines[0]!r}"
    if args[0] != "__argparse__":  # the line names the command (it once said "depotbench None")
        assert lines[0].startswith(f"depotbench {args[0]}: "), lines[0]
    assert snapshot(tmp) == before, "the input changed"
    assert sorted(p.name for p in tmp.rglob("*")) == listing, "something was written"


class _no_exit:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def write(name: str, content: str | bytes) -> Callable[[Path], None]:
    def make(tmp: Path) -> None:
        path = tmp / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content if isinstance(content, bytes) else content.encode())

    return make


# -- 1. scenario specs ------------------------------------------------------------------------------

SPEC_HEAD = "name: f\nframes: 2\nimage: {width: 64, height: 48}\nintrinsics: {fx: 52.5}\n"
SPECS: dict[str, tuple[str | bytes, str]] = {
    "fx_inf": ("name: f\nintrinsics: {fx: .inf}\n", "intrinsics.fx"),
    "fx_nan": ("name: f\nintrinsics: {fx: .nan}\n", "intrinsics.fx"),
    "fx_tiny": ("name: f\nintrinsics: {fx: 0.001}\n", "intrinsics.fx"),
    "fx_huge": ("name: f\nintrinsics: {fx: 1.0e9}\n", "intrinsics.fx"),
    "fx_zero": ("name: f\nintrinsics: {fx: 0}\n", "intrinsics.fx"),
    "position_nan": ("name: f\ncamera: {position_m: [0, .nan, 1]}\n", "camera.position_m"),
    "target_inf": ("name: f\ncamera: {target_m: [0, .inf, 1]}\n", "camera.target_m"),
    "camera_above_ceiling": (
        "name: f\ncamera: {position_m: [0, 0, 5], target_m: [0, 0, 0]}\n",
        "camera.position_m",
    ),
    "camera_in_floor": ("name: f\ncamera: {position_m: [0, 0, -1]}\n", "camera.position_m"),
    "camera_outside_x": ("name: f\ncamera: {position_m: [30, 0, 1.5]}\n", "camera.position_m"),
    "camera_on_target": (
        "name: f\ncamera: {position_m: [1, 1, 1], target_m: [1, 1, 1]}\n",
        "camera.target_m",
    ),
    "speed_nan": ("name: f\nactors: [{kind: person, speed_mps: .nan}]\n", "actors.0.speed_mps"),
    "speed_negative": ("name: f\nactors: [{kind: dog, speed_mps: -1}]\n", "actors.0.speed_mps"),
    "speed_range_reversed": ("name: f\nactors: [{kind: dog, speed_mps: [2, 1]}]\n", "actors.0.speed_mps"),
    "waypoint_inf": (
        "name: f\nactors: [{kind: person, waypoints: [[0, 0], [.inf, 1]]}]\n",
        "actors.0.waypoints",
    ),
    "waypoints_identical": (
        "name: f\nactors: [{kind: person, waypoints: [[1, 1], [1, 1]]}]\n",
        "actors.0.waypoints",
    ),
    "waypoints_outside": (
        "name: f\nactors: [{kind: person, waypoints: [[0, 0], [40, 0]]}]\n",
        "actors.0.waypoints.1",
    ),
    "waypoint_one": ("name: f\nactors: [{kind: person, waypoints: [[0, 0]]}]\n", "actors.0"),
    "waypoint_three_numbers": (
        "name: f\nactors: [{kind: cat, waypoints: [[0, 0, 0], [1, 1]]}]\n",
        "actors.0.waypoints",
    ),
    "chair_nan": ("name: f\nchairs: [{position_m: [.nan, 0]}]\n", "chairs.0.position_m"),
    "chair_outside": ("name: f\nchairs: [{position_m: [0, 90]}]\n", "chairs.0.position_m"),
    "light_inf": ("name: f\nlighting: {intensity: .inf}\n", "lighting.intensity"),
    "sensor_noise_nan": ("name: f\nsensor: {rgb_noise_sigma: .nan}\n", "sensor"),
    "depth_range_reversed": ("name: f\nsensor: {depth_range_m: [5, 1]}\n", "sensor"),
    "hall_inf": ("name: f\nlayout: {size_m: [.inf, 10]}\n", "layout.size_m"),
    "duration_inf": ("name: f\nduration_s: .inf\n", "duration_s"),
    "fps_nan": ("name: f\nfps: .nan\n", "fps"),
    "frames_text": ("name: f\nframes: ten\n", "frames"),
    "frames_zero": ("name: f\nframes: 0\n", "frames"),
    "seed_negative": ("name: f\nseed: -1\n", "seed"),
    "seed_huge": ("name: f\nseed: 1099511627776\n", "seed"),
    "kind_unknown": ("name: f\nactors: [{kind: dragon}]\n", "actors.0.kind"),
    "count_negative": ("name: f\nactors: [{kind: dog, count: -2}]\n", "actors.0.count"),
    "actors_not_list": ("name: f\nactors: 3\n", "actors"),
    "unknown_field": ("name: f\ncamra: {motion: xyz}\n", "camra"),
    "name_slash": ("name: ../../etc\n", "name"),
    "image_tiny": ("name: f\nimage: {width: 4}\n", "image.width"),
    "python_tag": ("name: !!python/object/apply:os.system ['true']\n", "not valid YAML"),
    "billion_laughs": (
        "a: &a [x, x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
        "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c]\n"
        "e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]\nf: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e, *e]\n"
        "name: [*f, *f, *f, *f, *f, *f, *f, *f, *f, *f]\n",
        "expands to more than",
    ),
    "recursive_alias": ("name: &a [*a]\n", "nested"),
    "deep_nesting": ("name: " + "[" * 5000 + "]" * 5000 + "\n", "nested"),
    "moderately_deep": ("name: " + "[" * 40 + "]" * 40 + "\n", "nested more than 32"),
    "empty": ("", "empty"),
    "top_level_list": ("- name: f\n", "mapping"),
    "binary": (b"\x00\xff\xfe\x89PNG", "not a text file"),
    "latin1": ("name: caf\xe9\n".encode("latin-1"), "not a text file"),
    "oversized": ("name: f\n" + "# padding\n" * 120_000, "1 MiB limit"),
    "frames_and_duration": ("name: f\nframes: 3\nduration_s: 1\n", "frames"),
    "pusher_without_chairs": ("name: f\nactors: [{kind: chair_pusher}]\n", "chairs"),
}


def _spec_cases() -> dict[str, Case]:
    cases = {}
    for name, (content, field) in SPECS.items():
        make = write(f"{name}.yaml", content)
        cases[f"spec-validate-{name}"] = Case(make, ("validate", f"{{tmp}}/{name}.yaml"), field)
        cases[f"spec-generate-{name}"] = Case(
            make, ("generate", f"{{tmp}}/{name}.yaml", "-o", "{tmp}/out"), f"{name}.yaml"
        )
    cases["spec-directory"] = Case(
        lambda tmp: (tmp / "d.yaml").mkdir(), ("validate", "{tmp}/d.yaml"), "directory"
    )
    cases["spec-missing"] = Case(lambda tmp: None, ("validate", "{tmp}/none.yaml"), "no such file")
    cases["spec-fifo"] = Case(
        lambda tmp: os.mkfifo(tmp / "p.yaml"), ("validate", "{tmp}/p.yaml"), "not a regular"
    )
    return cases


# -- 2. suites ------------------------------------------------------------------------------------------

SUITES: dict[str, tuple[str, str]] = {
    "huge_grid": (
        "suite: s\nbase: smoke\ngrid:\n"
        + "".join(f"  k{k}: [{', '.join(map(str, range(20)))}]\n" for k in range(8)),
        "limit of 10000",
    ),
    "unknown_knob": ("suite: s\nbase: smoke\ngrid: {camra.motion: [xyz]}\n", "camra"),
    "knob_index": ("suite: s\nbase: smoke\ngrid: {actors.7.count: [1]}\n", "actors.7.count"),
    "knob_through_scalar": ("suite: s\nbase: smoke\ngrid: {seed.x: [1]}\n", "seed.x"),
    "knob_bad_value": ("suite: s\nbase: smoke\ngrid: {actors.0.speed_mps: [1, 99]}\n", "actors.0.speed_mps"),
    "empty_values": ("suite: s\nbase: smoke\ngrid: {seed: []}\n", "at least one value"),
    "no_seeds": ("suite: s\nbase: smoke\nseeds: []\n", "seeds"),
    "negative_seed": ("suite: s\nbase: smoke\nseeds: [-1]\n", "seeds.0"),
    "grid_and_random": (
        "suite: s\nbase: smoke\ngrid: {seed: [1]}\nrandom: {count: 2, knobs: {seed: {int: [0, 3]}}}\n",
        "grid or random",
    ),
    "random_reversed": (
        "suite: s\nbase: smoke\nrandom: {count: 2, knobs: {seed: {int: [5, 1]}}}\n",
        "low <= high",
    ),
    "random_zero": (
        "suite: s\nbase: smoke\nrandom: {count: 0, knobs: {seed: {int: [0, 3]}}}\n",
        "random.count",
    ),
    "random_two_draws": (
        "suite: s\nbase: smoke\nrandom: {count: 1, knobs: {seed: {int: [0, 3], uniform: [0, 1]}}}\n",
        "exactly one",
    ),
    "base_missing": ("suite: s\nbase: nowhere.yaml\n", "nowhere.yaml"),
    "suite_name": ("suite: 'a/b'\nbase: smoke\n", "suite"),
    "override_bad": ("suite: s\nbase: smoke\noverrides: {frames: -4}\n", "frames"),
    "override_inf": ("suite: s\nbase: smoke\noverrides: {fps: .inf}\n", "fps"),
    "suite_unknown_field": ("suite: s\nbase: smoke\ngird: {}\n", "gird"),
}


def _suite_cases() -> dict[str, Case]:
    cases = {}
    for name, (content, needle) in SUITES.items():
        make = write(f"{name}.yaml", content)
        cases[f"suite-validate-{name}"] = Case(make, ("validate", f"{{tmp}}/{name}.yaml"), needle)
        cases[f"suite-generate-{name}"] = Case(
            make, ("generate", f"{{tmp}}/{name}.yaml", "-o", "{tmp}/out"), f"{name}.yaml"
        )
    return cases


# -- 3. sequence folders: each file of the format corrupted --------------------------------------


def sequence_case(corrupt: Callable[[Path], None], needle: str, command: str = "run") -> Case:
    def make(tmp: Path) -> None:
        write_sequence(tmp / "seq", n=4, with_flow=False)
        corrupt(tmp / "seq")

    if command == "run":
        args = ("run", "{tmp}/seq", "-o", "{tmp}/out", "--detector", "none")
    else:
        args = ("preview", "{tmp}/seq", "--frames", "0", "1", "2", "-o", "{tmp}/out.png")
    return Case(make, args, needle.replace("SEQ", "{tmp}/seq"))


def frame_file(seq: Path, folder: str, index: int = 2) -> Path:
    return sorted((seq / folder).iterdir())[index]


def edit_line(name: str, line: int, text: str) -> Callable[[Path], None]:
    def corrupt(seq: Path) -> None:
        lines = (seq / name).read_text().splitlines()
        lines[line - 1] = text
        (seq / name).write_text("\n".join(lines) + "\n")

    return corrupt


def replace_text(name: str, old: str, new: str) -> Callable[[Path], None]:
    def corrupt(seq: Path) -> None:
        text = (seq / name).read_text()
        assert old in text, (name, old)
        (seq / name).write_text(text.replace(old, new, 1))

    return corrupt


def both(*corruptions: Callable[[Path], None]) -> Callable[[Path], None]:
    def corrupt(seq: Path) -> None:
        for corruption in corruptions:
            corruption(seq)

    return corrupt


def set_bytes(name: str, content: bytes) -> Callable[[Path], None]:
    return lambda seq: (seq / name).write_bytes(content)


def remove(name: str) -> Callable[[Path], None]:
    return lambda seq: (seq / name).unlink()


def without_associations(then: Callable[[Path], None]) -> Callable[[Path], None]:
    def corrupt(seq: Path) -> None:
        (seq / "associations.txt").unlink()
        then(seq)

    return corrupt


def png(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", image)[1].tobytes()


def forged_png(width: int, height: int) -> bytes:
    """A PNG whose header declares ``width`` x ``height`` (a decompression bomb's first bytes)."""
    import struct
    import zlib

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    return (
        b"\x89PNG\r\n\x1a\n"
        + struct.pack(">I", len(ihdr))
        + chunk
        + struct.pack(">I", zlib.crc32(chunk))
        + b"\x00" * 64
    )


def frame_bytes(folder: str, content: Callable[[], bytes]) -> Callable[[Path], None]:
    return lambda seq: frame_file(seq, folder).write_bytes(content())


def frame_removed(folder: str) -> Callable[[Path], None]:
    return lambda seq: frame_file(seq, folder).unlink()


def link(name: str, target: str) -> Callable[[Path], None]:
    def corrupt(seq: Path) -> None:
        (seq / name).unlink()
        (seq / name).symlink_to(target)

    return corrupt


def object_record(line: int, old: str, new: str) -> Callable[[Path], None]:
    def corrupt(seq: Path) -> None:
        path = seq / "gt" / "objects.jsonl"
        lines = path.read_text().splitlines()
        assert old in lines[line - 1]
        lines[line - 1] = lines[line - 1].replace(old, new, 1)
        path.write_text("\n".join(lines) + "\n")

    return corrupt


def shift_list(path: Path, seconds: float) -> None:
    rows = [line.split() for line in path.read_text().splitlines() if not line.startswith("#")]
    path.write_text("".join(f"{float(t) + seconds:.6f} {name}\n" for t, name in rows))


def flip_byte(path: Path, offset: int) -> None:
    """Corrupt one byte; libpng then complains on the process's stderr, which must not leak."""
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


def keep_records(n: int) -> Callable[[Path], None]:
    def corrupt(seq: Path) -> None:
        path = seq / "gt" / "objects.jsonl"
        path.write_text("\n".join(path.read_text().splitlines()[:n]) + "\n")

    return corrupt


def _sequence_cases() -> dict[str, Case]:
    a = "associations.txt"
    gt = "groundtruth.txt"
    cam = "camera.yaml"
    cases = {
        "assoc-empty": sequence_case(set_bytes(a, b""), "associations.txt: lists no frames"),
        "assoc-three-fields": sequence_case(edit_line(a, 2, "1.0 rgb/x.png 1.0"), "associations.txt:2"),
        "assoc-bad-time": sequence_case(
            edit_line(a, 2, "abc rgb/1.033333.png 1.0 depth/1.033333.png"), "associations.txt:2"
        ),
        "assoc-duplicate-time": sequence_case(
            edit_line(a, 2, "1.000000 rgb/1.033333.png 1.033333 depth/1.033333.png"), "associations.txt:2"
        ),
        "assoc-missing-frame": sequence_case(
            edit_line(a, 2, "1.033333 rgb/9.png 1.033333 depth/1.033333.png"), "associations.txt:2"
        ),
        "assoc-outside": sequence_case(
            edit_line(a, 2, "1.033333 ../x.png 1.033333 depth/1.033333.png"), "outside the sequence"
        ),
        "assoc-absolute": sequence_case(
            edit_line(a, 2, "1.033333 /etc/hostname 1.033333 depth/1.033333.png"), "outside the sequence"
        ),
        "assoc-binary": sequence_case(set_bytes(a, b"\xff\xfe\x00\x01"), "associations.txt: not a text file"),
        "assoc-device": sequence_case(link(a, "/dev/zero"), "associations.txt: is not a regular file"),
        "assoc-directory": sequence_case(
            lambda s: ((s / a).unlink(), (s / a).mkdir()), "associations.txt: is a directory"
        ),
        "rgb-list-missing": sequence_case(
            without_associations(remove("rgb.txt")), "rgb.txt: file is missing"
        ),
        "rgb-list-bad-time": sequence_case(
            without_associations(edit_line("rgb.txt", 4, "x rgb/1.000000.png")), "rgb.txt:4"
        ),
        "rgb-list-outside": sequence_case(
            without_associations(edit_line("rgb.txt", 4, "1.000000 ../../x.png")), "rgb.txt:4"
        ),
        "depth-list-far": sequence_case(
            without_associations(lambda seq: shift_list(seq / "depth.txt", 5.0)), "no depth frame within"
        ),
        "depth-list-unsorted": sequence_case(
            without_associations(edit_line("depth.txt", 5, "0.5 depth/1.033333.png")), "depth.txt:5"
        ),
        "gt-missing": sequence_case(remove(gt), "groundtruth.txt: file is missing"),
        "gt-nan": sequence_case(edit_line(gt, 3, "1.000000 nan 0 0 0 0 0 1"), "groundtruth.txt:3"),
        "gt-quaternion": sequence_case(edit_line(gt, 3, "1.000000 0 0 0 0 0 0 2"), "groundtruth.txt:3"),
        "gt-seven-fields": sequence_case(edit_line(gt, 3, "1.000000 0 0 0 0 0 1"), "groundtruth.txt:3"),
        "gt-too-few": sequence_case(
            edit_line(gt, 3, "# gone"), "groundtruth.txt: holds 3 poses for 4 frames"
        ),
        "gt-other-time": sequence_case(
            edit_line(gt, 3, "1.010000 0 0 0 0 0 0 1"),
            "groundtruth.txt:3: timestamp 1.010000 differs from frame 0",
        ),
        "gt-far": sequence_case(edit_line(gt, 3, "1.000000 1e20 0 0 0 0 0 1"), "groundtruth.txt:3"),
        "camera-missing": sequence_case(remove(cam), "camera.yaml: file is missing"),
        "camera-garbage": sequence_case(set_bytes(cam, b"{{{{ not yaml"), "camera.yaml"),
        "camera-no-fx": sequence_case(replace_text(cam, "Camera.fx:", "Camera.fz:"), "missing key Camera.fx"),
        "camera-fx-text": sequence_case(
            replace_text(cam, "Camera.fx: 50.0", "Camera.fx: fifty"), "Camera.fx must be a number"
        ),
        "camera-fx-negative": sequence_case(
            replace_text(cam, "Camera.fx: 50.0", "Camera.fx: -50"), "camera.yaml"
        ),
        "camera-width-zero": sequence_case(
            replace_text(cam, "Camera.width: 64", "Camera.width: 0"), "Camera.width"
        ),
        "camera-width-fraction": sequence_case(
            replace_text(cam, "Camera.width: 64", "Camera.width: 64.5"), "Camera.width"
        ),
        "camera-width-other": sequence_case(
            both(
                replace_text(cam, "Camera.width: 64", "Camera.width: 128"),
                replace_text("meta.json", '"image_size": [\n    64,', '"image_size": [\n    128,'),
            ),
            "is 64x48, the camera is 128x48",
        ),
        "camera-depth-factor": sequence_case(
            replace_text(cam, "DepthMapFactor: 5000.0", "DepthMapFactor: 0"), "DepthMapFactor = 0 is outside"
        ),
        "camera-fx-tiny": sequence_case(
            replace_text(cam, "Camera.fx: 50.0", "Camera.fx: 1e-300"), "Camera.fx = 1e-300"
        ),
        "camera-cx-huge": sequence_case(
            replace_text(cam, "Camera.cx: 31.5", "Camera.cx: 1e300"), "Camera.cx = 1e+300"
        ),
        "camera-meta-size": sequence_case(
            replace_text("meta.json", '"image_size": [\n    64,', '"image_size": [\n    640,'),
            "image_size is [640, 48]",
        ),
        "camera-nested": sequence_case(
            replace_text(cam, "Camera.fx: 50.0", "Camera.fx: " + "[" * 50_000 + "]" * 50_000),
            "nested more than 16",
        ),
        "assoc-far-depth": sequence_case(
            edit_line(a, 2, "1.033333 rgb/1.033333.png 99.0 depth/1.033333.png"),
            "associations.txt:2: depth is",
        ),
        "assoc-same-file": sequence_case(
            edit_line(a, 2, "1.033333 rgb/1.000000.png 1.033333 depth/1.033333.png"),
            "associations.txt:2: frame file rgb/1.000000.png is listed again",
        ),
        "meta-version-bool": sequence_case(
            replace_text("meta.json", '"format_version": 1', '"format_version": true'), "format_version True"
        ),
        "meta-huge-int": sequence_case(
            replace_text("meta.json", '"fps": 30.0', '"fps": ' + "9" * 5000), "meta.json"
        ),
        "objects-box-outside": sequence_case(
            object_record(3, '"box_xyxy":[30,10,40,20]', '"box_xyxy":[30,10,40000,20]'),
            "exceeds the 64x48 frame",
        ),
        "camera-fps": sequence_case(replace_text(cam, "Camera.fps: 30.0", "Camera.fps: -1"), "Camera.fps"),
        "camera-k1-nan": sequence_case(replace_text(cam, "Camera.k1: 0.0", "Camera.k1: .nan"), "distortion"),
        "camera-huge": sequence_case(set_bytes(cam, b"%YAML:1.0\n" + b"#" * (2 << 20)), "camera.yaml: is"),
        "meta-not-json": sequence_case(set_bytes("meta.json", b"{ nope"), "meta.json:1: not valid JSON"),
        "meta-list": sequence_case(set_bytes("meta.json", b"[1, 2]"), "meta.json: must hold a JSON object"),
        "meta-version": sequence_case(
            replace_text("meta.json", '"format_version": 1', '"format_version": 99'), "format_version 99"
        ),
        "meta-fps-text": sequence_case(
            replace_text("meta.json", '"fps": 30.0', '"fps": "fast"'), "fps must be a number"
        ),
        "meta-fps-zero": sequence_case(
            replace_text("meta.json", '"fps": 30.0', '"fps": 0'), "fps must be a number"
        ),
        "meta-device": sequence_case(link("meta.json", "/dev/zero"), "meta.json: is not a regular file"),
        "objects-missing": sequence_case(remove("gt/objects.jsonl"), "objects.jsonl: file is missing"),
        "objects-bad-json": sequence_case(object_record(2, "{", "{{"), "objects.jsonl:2"),
        "objects-too-few": sequence_case(keep_records(3), "objects.jsonl: holds 3 records for 4 frames"),
        "objects-other-time": sequence_case(
            object_record(2, '"timestamp":"1.033333"', '"timestamp":"7.0"'), "objects.jsonl:2"
        ),
        "objects-prior": sequence_case(
            object_record(3, '"prior":"dynamic"', '"prior":"bogus"'), "objects.jsonl:3"
        ),
        "objects-box": sequence_case(
            object_record(3, '"box_xyxy":[30,10,40,20]', '"box_xyxy":[30,10,40]'), "objects.jsonl:3"
        ),
        "objects-moving": sequence_case(
            object_record(3, '"moving":true', '"moving":"yes"'), "objects.jsonl:3"
        ),
        "objects-unoccluded-below-visible": sequence_case(
            object_record(3, '"unoccluded_pixels":160', '"unoccluded_pixels":50'), "objects.jsonl:3"
        ),
        "objects-truncated-not-bool": sequence_case(
            object_record(3, '"truncated":false', '"truncated":0'), "objects.jsonl:3"
        ),
        "objects-nan": sequence_case(
            object_record(3, '"position_m":[1.0', '"position_m":[NaN'), "objects.jsonl:3"
        ),
        "instances-missing": sequence_case(frame_removed("gt/instances"), "instance image is missing"),
        "instances-8bit": sequence_case(
            frame_bytes("gt/instances", lambda: png(np.zeros((48, 64), np.uint8))),
            "instance image must be a 16-bit",
        ),
        "rgb-truncated": sequence_case(
            lambda s: frame_file(s, "rgb").write_bytes(frame_file(s, "rgb").read_bytes()[:80]),
            "cannot be decoded",
        ),
        "rgb-not-png": sequence_case(frame_bytes("rgb", lambda: b"GIF89a...."), "is not a PNG image"),
        "rgb-header-crc": sequence_case(lambda s: flip_byte(frame_file(s, "rgb"), 29), "(IHDR: CRC error)"),
        "rgb-bad-zlib": sequence_case(
            lambda s: flip_byte(frame_file(s, "rgb"), 50), "cannot be decoded as a PNG image"
        ),
        "rgb-empty": sequence_case(frame_bytes("rgb", lambda: b""), "is not a PNG image"),
        "rgb-bomb": sequence_case(
            frame_bytes("rgb", lambda: forged_png(30000, 30000)), "image is 30000x30000"
        ),
        "rgb-small": sequence_case(
            frame_bytes("rgb", lambda: png(np.zeros((24, 32, 3), np.uint8))), "image is 32x24"
        ),
        "rgb-16bit": sequence_case(
            frame_bytes("rgb", lambda: png(np.zeros((48, 64, 3), np.uint16))), "RGB must be 8-bit"
        ),
        "rgb-directory": sequence_case(
            lambda s: (frame_file(s, "rgb").unlink(), (s / "rgb" / "1.066667.png").mkdir()),
            "associations.txt:3",
        ),
        "depth-8bit": sequence_case(
            frame_bytes("depth", lambda: png(np.zeros((48, 64), np.uint8))), "depth must be a 16-bit"
        ),
        "depth-3-channels": sequence_case(
            frame_bytes("depth", lambda: png(np.zeros((48, 64, 3), np.uint16))),
            "depth must be a 16-bit single-channel",
        ),
        "depth-missing": sequence_case(frame_removed("depth"), "associations.txt:3"),
        "not-a-folder": Case(
            lambda tmp: None, ("run", "{tmp}/nowhere", "-o", "{tmp}/out"), "no such directory"
        ),
        "preview-bomb": sequence_case(
            frame_bytes("rgb", lambda: forged_png(30000, 30000)), "30000x30000", "preview"
        ),
        "preview-objects": sequence_case(
            object_record(1, '"moving":true', '"moving":1'), "objects.jsonl:1", "preview"
        ),
        "preview-truncated": sequence_case(
            lambda s: frame_file(s, "gt/instances").write_bytes(
                frame_file(s, "gt/instances").read_bytes()[:70]
            ),
            "cannot be decoded",
            "preview",
        ),
    }
    return {f"sequence-{name}": case for name, case in cases.items()}


# -- 4. trajectories ---------------------------------------------------------------------------------

GOOD = "".join(f"{1 + 0.1 * k:.6f} {0.1 * k:.3f} {0.02 * k * k:.3f} 0.5 0 0 0 1\n" for k in range(12))

TRAJECTORIES: dict[str, tuple[str | bytes, str]] = {
    "empty": ("", "holds no poses"),
    "comments_only": ("# a\n# b\n", "holds no poses"),
    "seven_fields": (GOOD + "3.0 0 0 0 0 0 1\n", ":13: expected 8 fields"),
    "nine_fields": ("1.0 0 0 0 0 0 0 1 9\n" + GOOD, ":1: expected 8 fields"),
    "text_time": ("one 0 0 0 0 0 0 1\n" + GOOD, ":1: field 'one' is not a number"),
    "nan": (GOOD + "5.0 nan 0 0 0 0 0 1\n", ":13: pose holds NaN"),
    "inf": (GOOD + "5.0 0 inf 0 0 0 0 1\n", ":13: pose holds NaN or infinity"),
    "zero_quaternion": (GOOD + "5.0 0 0 0 0 0 0 0\n", ":13: quaternion"),
    "far": (GOOD + "5.0 1e30 0 0 0 0 0 1\n", ":13: position is beyond"),
    "huge_quaternion": (GOOD + "5.0 0 0 0 1.34e154 0 0 1\n", ":13: quaternion"),
    "binary": (b"\x00\x01\xff\xfe", "not a text file"),
    "one_pose": ("1.0 0 0 0 0 0 0 1\n", "cannot align"),
    "two_poses": ("1.0 0 0 0 0 0 0 1\n1.1 1 0 0 0 0 0 1\n", "cannot align"),
    "collinear": ("".join(f"{1 + 0.1 * k:.6f} {k} 0 0 0 0 0 1\n" for k in range(12)), "degenerate"),
    "no_overlap": ("".join(f"{100 + k:.6f} {k} {k * k} 0 0 0 0 1\n" for k in range(12)), "no timestamps"),
    "oversized": ("# x\n" * 9_000_000, "32 MiB limit"),
}


def _trajectory_cases() -> dict[str, Case]:
    cases = {}
    for name, (content, needle) in TRAJECTORIES.items():

        def make(tmp: Path, content=content) -> None:
            write("gt.txt", GOOD)(tmp)
            write("est.txt", content)(tmp)

        cases[f"trajectory-{name}"] = Case(make, ("eval", "{tmp}/gt.txt", "{tmp}/est.txt"), needle)
    cases["trajectory-directory"] = Case(
        lambda tmp: (write("gt.txt", GOOD)(tmp), (tmp / "est.txt").mkdir()),
        ("eval", "{tmp}/gt.txt", "{tmp}/est.txt"),
        "est.txt: is a directory",
    )
    cases["trajectory-device"] = Case(
        lambda tmp: write("gt.txt", GOOD)(tmp),
        ("eval", "{tmp}/gt.txt", "/dev/zero"),
        "/dev/zero: is not a regular",
    )
    cases["trajectory-missing"] = Case(
        lambda tmp: write("gt.txt", GOOD)(tmp),
        ("eval", "{tmp}/gt.txt", "{tmp}/none.txt"),
        "none.txt: file is missing",
    )
    return cases


# -- 5. command lines ---------------------------------------------------------------------------------


def _command_cases() -> dict[str, Case]:
    seq = lambda tmp: write_sequence(tmp / "seq", n=3, with_flow=False)  # noqa: E731
    gt = write("gt.txt", GOOD)
    evaluate = ("eval", "{tmp}/gt.txt", "{tmp}/gt.txt")
    run = ("run", "{tmp}/seq", "-o", "{tmp}/out")
    nothing = lambda tmp: None  # noqa: E731
    cases = {
        "eval-max-diff": Case(gt, (*evaluate, "--max-diff", "-1"), "max_diff_s"),
        "eval-delta-zero": Case(gt, ("__argparse__", *evaluate, "--rpe-delta", "0"), "--rpe-delta"),
        "eval-delta-fraction": Case(gt, (*evaluate, "--rpe-delta", "1.5"), "whole number"),
        "eval-delta-huge": Case(gt, (*evaluate, "--rpe-delta", "1e9"), "no pose pairs"),
        "eval-align": Case(gt, ("__argparse__", *evaluate, "--align", "sim4"), "--align"),
        "eval-delta-word": Case(
            gt, ("__argparse__", *evaluate, "--rpe-delta", "one"), "must be a number, got 'one'"
        ),
        "workers-word": Case(  # probe M9: "invalid _workers value: 'two'" named a private function
            nothing,
            ("__argparse__", "generate", "smoke", "-o", "{tmp}/out", "--workers", "two"),
            "whole number of workers",
        ),
        "eval-missing-arg": Case(gt, ("__argparse__", "eval", "{tmp}/gt.txt"), "estimate"),
        "generate-seed": Case(nothing, ("generate", "smoke", "-o", "{tmp}/out", "--seed", "-1"), "--seed -1"),
        "generate-seed-huge": Case(
            nothing, ("generate", "smoke", "-o", "{tmp}/out", "--seed", "99999999999"), "--seed"
        ),
        "generate-frames-zero": Case(
            nothing, ("generate", "smoke", "-o", "{tmp}/out", "--frames", "0"), "--frames 0"
        ),
        "generate-frames-huge": Case(
            nothing, ("generate", "smoke", "-o", "{tmp}/out", "--frames", "100001"), "--frames 100001"
        ),
        "generate-workers": Case(
            nothing, ("__argparse__", "generate", "smoke", "-o", "{tmp}/out", "--workers", "0"), "--workers"
        ),
        "generate-unknown": Case(
            nothing, ("generate", "no_such_scene", "-o", "{tmp}/out"), "no library scenario named"
        ),
        "generate-onto-file": Case(
            write("taken", "x"), ("generate", "smoke", "-o", "{tmp}/taken", "--overwrite"), "is a file"
        ),
        "generate-onto-folder": Case(
            write("mine/thesis.tex", "x"),
            ("generate", "smoke", "-o", "{tmp}/mine", "--overwrite"),
            "not written by depotbench",
        ),
        "generate-suite-seed": Case(
            write("s.yaml", "suite: s\nbase: smoke\n"),
            ("generate", "{tmp}/s.yaml", "-o", "{tmp}/out", "--seed", "3"),
            "apply to one scenario",
        ),
        "run-set-unknown": Case(seq, (*run, "--set", "kk=2"), "unknown setting 'kk'"),
        "run-set-text": Case(seq, (*run, "--set", "k=abc"), "not a number"),
        "run-set-nan": Case(seq, (*run, "--set", "k=nan"), "out of range"),
        "run-set-huge": Case(seq, (*run, "--set", "k=1e9"), "out of range"),
        "run-set-no-equals": Case(seq, (*run, "--set", "k"), "expected NAME=VALUE"),
        "run-set-bool": Case(seq, (*run, "--set", "motion_model_ransac=maybe"), "not true or false"),
        "run-set-contradiction": Case(
            seq, (*run, "--set", "min_depth_m=4", "--set", "max_depth_m=3"), "min_depth_m"
        ),
        "run-set-fast": Case(seq, (*run, "--set", "fast_threshold_min=30"), "fast_threshold_min"),
        "run-strategy": Case(seq, ("__argparse__", *run, "--strategy", "magic"), "--strategy"),
        "run-detector": Case(seq, (*run, "--detector", "yolo99"), "unknown detector 'yolo99'"),
        "run-detector-path-gt": Case(
            seq, (*run, "--detector", "groundtruth:x.onnx"), "only onnx takes a model path"
        ),
        "run-onnx-missing": Case(seq, (*run, "--detector", "onnx:{tmp}/no.onnx"), "no.onnx does not exist"),
        "run-onnx-empty-path": Case(seq, (*run, "--detector", "onnx:"), "empty model path"),
        "run-onnx-not-a-model": Case(
            lambda tmp: (seq(tmp), write("m.onnx", "not a model")(tmp)),
            (*run, "--detector", "onnx:{tmp}/m.onnx"),
            "m.onnx: not a usable ONNX model",
        ),
        "run-fault-unknown": Case(seq, (*run, "--fault", "gremlins=1"), "unknown fault 'gremlins'"),
        "run-fault-range": Case(seq, (*run, "--fault", "miss=1.5"), "fault miss = 1.5 is out of range"),
        "run-fault-nan": Case(seq, (*run, "--fault", "jitter=nan"), "fault jitter = nan is out of range"),
        "run-fault-text": Case(seq, (*run, "--fault", "latency=soon"), "not a number"),
        "run-fault-no-equals": Case(seq, (*run, "--fault", "miss"), "--fault 'miss': expected NAME=VALUE"),
        "run-fault-confusion": Case(
            seq, (*run, "--fault", "confusion=person->dog"), "not 'true class->reported class:probability'"
        ),
        "run-fault-confusion-sum": Case(
            seq, (*run, "--fault", "confusion=person->dog:0.7;person->cat:0.6"), "sum to 1.3 > 1"
        ),
        "run-fault-without-detector": Case(
            seq, (*run, "--detector", "none", "--fault", "miss=0.1"), "--fault needs a detector"
        ),
        "run-detector-set-gt": Case(
            seq, (*run, "--detector-set", "confidence=0.5"), "only --detector onnx takes it"
        ),
        "run-detector-set-unknown": Case(
            seq, (*run, "--detector", "onnx", "--detector-set", "anchors=3"), "unknown detector setting"
        ),
        "run-detector-set-range": Case(
            seq, (*run, "--detector", "onnx", "--detector-set", "confidence=2"), "out of range [0, 1]"
        ),
        "run-class-prior": Case(
            seq, (*run, "--class-prior", "pig=sometimes"), "choose one of dynamic, potential, static"
        ),
        "run-exists": Case(
            lambda tmp: (seq(tmp), write("out/x", "x")(tmp)), run, "not written by depotbench"
        ),
        "run-onto-input": Case(seq, ("run", "{tmp}/seq", "-o", "{tmp}/seq", "--overwrite"), "is the input"),
        "run-onto-parent": Case(seq, ("run", "{tmp}/seq", "-o", "{tmp}", "--overwrite"), "holding the input"),
        "run-no-truth": Case(
            lambda tmp: (
                seq(tmp),
                (tmp / "seq" / "meta.json").unlink(),
                (tmp / "seq" / "groundtruth.txt").unlink(),
            ),
            (*run, "--strategy", "box_rule"),  # with none, a real folder runs (probe U4)
            "give --detector onnx",
        ),
        "detect-eval-real-tum": Case(
            lambda tmp: (
                seq(tmp),
                (tmp / "seq" / "meta.json").unlink(),
                (tmp / "seq" / "groundtruth.txt").unlink(),
            ),
            ("detect-eval", "{tmp}/seq", "--detector", "groundtruth"),
            "needs generated sequences",
        ),
        "detect-eval-none": Case(seq, ("detect-eval", "{tmp}/seq", "--detector", "none"), "needs a detector"),
        "detect-eval-min-pixels": Case(
            seq, ("detect-eval", "{tmp}/seq", "--min-pixels", "0"), "--min-pixels must be at least 1"
        ),
        "detect-eval-output-onto-input": Case(
            seq,
            ("detect-eval", "{tmp}/seq", "--detector", "groundtruth", "-o", "{tmp}/seq"),
            "is the input",
        ),
        "detect-eval-missing": Case(nothing, ("detect-eval", "{tmp}/nope"), "nope"),
        "export-onto-input": Case(seq, ("export-dataset", "{tmp}/seq", "-o", "{tmp}/seq"), "is the input"),
        "export-into-existing": Case(
            lambda tmp: (seq(tmp), write("ds/x", "x")(tmp)),
            ("export-dataset", "{tmp}/seq", "-o", "{tmp}/ds"),
            "not written by depotbench",
        ),
        "export-val-fraction": Case(
            seq, ("export-dataset", "{tmp}/seq", "-o", "{tmp}/ds", "--val-fraction", "1.5"), "--val-fraction"
        ),
        "export-every": Case(
            seq,
            ("export-dataset", "{tmp}/seq", "-o", "{tmp}/ds", "--every", "0"),
            "--every must be at least 1",
        ),
        "export-val-unknown": Case(
            seq, ("export-dataset", "{tmp}/seq", "-o", "{tmp}/ds", "--val", "other"), "--val other: not among"
        ),
        "export-same-name": Case(
            lambda tmp: (seq(tmp), write_sequence(tmp / "b" / "seq", n=3, with_flow=False)),
            ("export-dataset", "{tmp}/seq", "{tmp}/b/seq", "-o", "{tmp}/ds"),
            "two sequences are named 'seq'",
        ),
        "export-names-empty": Case(
            lambda tmp: (seq(tmp), write("names.txt", "\n\n")(tmp)),
            ("export-dataset", "{tmp}/seq", "-o", "{tmp}/ds", "--names", "{tmp}/names.txt"),
            "needs distinct class names",
        ),
        "export-real-tum": Case(
            lambda tmp: (
                seq(tmp),
                (tmp / "seq" / "meta.json").unlink(),
                (tmp / "seq" / "groundtruth.txt").unlink(),
            ),
            ("export-dataset", "{tmp}/seq", "-o", "{tmp}/ds"),
            "export needs generated sequences",
        ),
        "preview-range": Case(
            seq, ("preview", "{tmp}/seq", "--frames", "9", "-o", "{tmp}/p.png"), "frame 9 is out of range"
        ),
        "preview-negative": Case(
            seq, ("preview", "{tmp}/seq", "--frames", "-1", "-o", "{tmp}/p.png"), "frame -1"
        ),
        "preview-format": Case(seq, ("preview", "{tmp}/seq", "-o", "{tmp}/p.jpg"), "p.jpg"),
        "preview-folder": Case(
            lambda tmp: (seq(tmp), (tmp / "d.png").mkdir()),
            ("preview", "{tmp}/seq", "-o", "{tmp}/d.png"),
            "is a folder",
        ),
        "demo-workers": Case(
            nothing, ("__argparse__", "demo", "-o", "{tmp}/out", "--workers", "-3"), "--workers"
        ),
        "unknown-command": Case(nothing, ("__argparse__", "frobnicate"), "frobnicate"),
        "run-external-strategy": Case(
            seq, (*run, "--slam", "orbslam3", "--strategy", "box_rule"), "needs the built-in tracker"
        ),
        "run-external-set": Case(
            seq,
            (*run, "--slam", "cmd", "--command", "true", "--set", "k=2"),
            "--set k: --slam cmd takes only",
        ),
        "run-command-without-cmd": Case(
            seq, (*run, "--command", "slam {sequence}"), "--command applies to --slam cmd only"
        ),
        "run-cmd-without-command": Case(seq, (*run, "--slam", "cmd"), "--slam cmd needs --command"),
        "run-cmd-placeholder": Case(
            seq,
            (*run, "--slam", "cmd", "--command", "slam {calibration}"),
            "unknown placeholder {calibration}",
        ),
        "run-cmd-empty": Case(seq, (*run, "--slam", "cmd", "--command", "  "), "the template is empty"),
        "run-mask-without-boxes": Case(
            seq, (*run, "--strategy", "mask", "--detector", "none"), "needs boxes"
        ),
        "run-vocabulary-builtin": Case(seq, (*run, "--vocabulary", "{tmp}/v.txt"), "--vocabulary applies"),
        "run-timeout-zero": Case(
            seq, ("__argparse__", *run, "--slam", "cmd", "--command", "x", "--timeout", "0"), "--timeout"
        ),
        "vocab-branching": Case(
            nothing, ("vocab", "-o", "{tmp}/v.txt", "--branching", "50"), "--branching must lie in 2..20"
        ),
        "vocab-levels": Case(
            nothing, ("vocab", "-o", "{tmp}/v.txt", "--levels", "0"), "--levels must lie in 1..10"
        ),
        "sweep-missing-spec": Case(nothing, ("sweep", "{tmp}/none.yaml", "-o", "{tmp}/out"), "none.yaml"),
        "sweep-bad-yaml": Case(
            write("s.yaml", "sweep: [unclosed\n"), ("sweep", "{tmp}/s.yaml", "-o", "{tmp}/out"), "s.yaml"
        ),
        "sweep-missing-sequence": Case(
            write("s.yaml", "sweep: s\nsequences: [nowhere]\n"),
            ("sweep", "{tmp}/s.yaml", "-o", "{tmp}/out"),
            "sequences.0:",
        ),
        "sweep-missing-suite": Case(
            write("s.yaml", "sweep: s\nsuite: gone.yaml\n"),
            ("sweep", "{tmp}/s.yaml", "-o", "{tmp}/out"),
            "gone.yaml is not a file",
        ),
        "sweep-bad-detector": Case(
            lambda tmp: (
                seq(tmp),
                write("s.yaml", f"sweep: s\nsequences: [{tmp}/seq]\ndetectors: [yolo9]\n")(tmp),
            ),
            ("sweep", "{tmp}/s.yaml", "-o", "{tmp}/out"),
            "detectors.0: unknown detector 'yolo9'",
        ),
        "sweep-bad-tracker": Case(
            lambda tmp: (
                seq(tmp),
                write("s.yaml", f"sweep: s\nsequences: [{tmp}/seq]\ntrackers: [cmd]\n")(tmp),
            ),
            ("sweep", "{tmp}/s.yaml", "-o", "{tmp}/out"),
            "trackers.0: a cmd tracker needs a name and a command (a mapping)",
        ),
        "sweep-bad-threshold": Case(
            lambda tmp: (
                seq(tmp),
                write(
                    "s.yaml",
                    f"sweep: s\nsequences: [{tmp}/seq]\nstrategies: [prior_flow]\n"
                    "thresholds: {prior_flow: {k: {grid: [-1]}}}\n",
                )(tmp),
            ),
            ("sweep", "{tmp}/s.yaml", "-o", "{tmp}/out"),
            "thresholds.prior_flow",
        ),
        "sweep-address-local": Case(
            write("s.yaml", "sweep: s\nsequences: [x]\n"),
            ("sweep", "{tmp}/s.yaml", "-o", "{tmp}/out", "--address", "ray://h:1"),
            "--address applies to --backend ray only",
        ),
        "sweep-onto-foreign": Case(
            lambda tmp: (
                seq(tmp),
                write("s.yaml", f"sweep: s\nsequences: [{tmp}/seq]\n")(tmp),
                write("out/x", "x")(tmp),
            ),
            ("sweep", "{tmp}/s.yaml", "-o", "{tmp}/out"),
            "not written by depotbench",
        ),
        "sweep-workers": Case(
            nothing,
            ("__argparse__", "sweep", "{tmp}/s.yaml", "-o", "{tmp}/out", "--workers", "0"),
            "--workers",
        ),
        "check-missing-gates": Case(nothing, ("check", "{tmp}/none.yaml", "-o", "{tmp}/out"), "none.yaml"),
        "check-bad-yaml": Case(
            write("g.yaml", "gates: [unclosed\n"), ("check", "{tmp}/g.yaml", "-o", "{tmp}/out"), "g.yaml"
        ),
        "check-no-checks": Case(
            write("g.yaml", "gates: g\nrun: {sequences: [x]}\nchecks: []\n"),
            ("check", "{tmp}/g.yaml", "-o", "{tmp}/out"),
            "checks",
        ),
        "check-unknown-budget": Case(
            write(
                "g.yaml", "gates: g\nrun: {sequences: [x]}\nchecks: [{name: c, budgets: {speed: {max: 1}}}]\n"
            ),
            ("check", "{tmp}/g.yaml", "-o", "{tmp}/out"),
            "unknown budget 'speed'",
        ),
        "check-inverted-bound": Case(
            write(
                "g.yaml",
                "gates: g\nrun: {sequences: [x]}\nchecks: [{name: c, budgets: {ate_rmse_m: {min: 2, max: 1}}}]\n",
            ),
            ("check", "{tmp}/g.yaml", "-o", "{tmp}/out"),
            "min is above max",
        ),
        "check-nan-bound": Case(
            write(
                "g.yaml",
                "gates: g\nrun: {sequences: [x]}\nchecks: [{name: c, budgets: {ate_rmse_m: {max: .nan}}}]\n",
            ),
            ("check", "{tmp}/g.yaml", "-o", "{tmp}/out"),
            "finite",
        ),
        "check-missing-sequence": Case(
            write(
                "g.yaml",
                "gates: g\nrun: {sequences: [nowhere]}\nchecks: [{name: c, budgets: {ate_rmse_m: {max: 1}}}]\n",
            ),
            ("check", "{tmp}/g.yaml", "-o", "{tmp}/out"),
            "sequences.0:",
        ),
        "check-bad-threshold": Case(
            write(
                "g.yaml",
                "gates: g\nrun: {sequences: [x], strategies: [prior_flow], thresholds: {prior_flow: {k: {grid: [-1]}}}}\n"
                "checks: [{name: c, budgets: {ate_rmse_m: {max: 1}}}]\n",
            ),
            ("check", "{tmp}/g.yaml", "-o", "{tmp}/out"),
            "thresholds.prior_flow",
        ),
        "check-duplicate-names": Case(
            write(
                "g.yaml",
                "gates: g\nrun: {sequences: [x]}\n"
                "checks: [{name: c, budgets: {ate_rmse_m: {max: 1}}}, {name: c, budgets: {ate_rmse_m: {max: 1}}}]\n",
            ),
            ("check", "{tmp}/g.yaml", "-o", "{tmp}/out"),
            "unique",
        ),
        "report-missing": Case(
            nothing, ("report", "{tmp}/nothing", "-o", "{tmp}/out"), "nothing: no such folder"
        ),
        "report-neither": Case(
            write("folder/readme.txt", "x"),
            ("report", "{tmp}/folder", "-o", "{tmp}/out"),
            "neither a run folder",
        ),
        "report-bad-metrics": Case(
            write("run/metrics.json", "{not json"), ("report", "{tmp}/run", "-o", "{tmp}/out"), "metrics.json"
        ),
        "report-no-frames": Case(
            write("run/metrics.json", '{"tracker": "builtin", "strategy": "none", "detector": "none"}'),
            ("report", "{tmp}/run", "-o", "{tmp}/out"),
            "frames.csv",
        ),
        "report-rerun-exists": Case(
            lambda tmp: (write("run/metrics.json", "{}")(tmp), write("x.rrd", "mine")(tmp)),
            ("report", "{tmp}/run", "-o", "{tmp}/out", "--rerun", "{tmp}/x.rrd"),
            "x.rrd already exists",
        ),
        "report-rerun-not-a-run": Case(
            write("folder/readme.txt", "x"),
            ("report", "{tmp}/folder", "-o", "{tmp}/out", "--rerun", "{tmp}/x.rrd"),
            "not a run folder",
        ),
        "vocab-scene": Case(
            nothing,
            ("vocab", "-o", "{tmp}/v.txt", "--scenes", "atlantis"),
            "no library scenario named 'atlantis'",
        ),
        "vocab-exists": Case(
            write("v.txt", "x"), ("vocab", "-o", "{tmp}/v.txt", "--levels", "2"), "already exists"
        ),
    }
    return {f"command-{name}": case for name, case in cases.items()}


CASES = {**_spec_cases(), **_suite_cases(), **_sequence_cases(), **_trajectory_cases(), **_command_cases()}


def test_the_suite_covers_at_least_100_distinct_inputs_of_each_kind_together():
    kinds = {name.split("-")[0] for name in CASES}
    assert kinds == {"spec", "suite", "sequence", "trajectory", "command"}
    assert len(CASES) >= 100


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_gets_one_line_and_exit_2(name: str, tmp_path: Path, capfd):
    check_refused(tmp_path, capfd, CASES[name])


# -- hypothesis: random corruptions -------------------------------------------------------------------

JUNK = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "", "1e400", "0x1p3", "--", "1,5", "\x00", "é", "1e-400"]),
    st.text(max_size=8),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)


@settings(
    max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(line=st.integers(0, 11), field=st.integers(0, 9), junk=JUNK)
def test_any_corrupted_trajectory_is_evaluated_or_refused_by_line(tmp_path: Path, capfd, line, field, junk):
    rows = [r.split() for r in GOOD.splitlines()]
    if field < 8:
        rows[line][field] = junk
    else:
        rows[line].append(junk)
    est = tmp_path / "est.txt"
    est.write_text("\n".join(" ".join(r) for r in rows) + "\n", encoding="utf-8", errors="surrogateescape")
    (tmp_path / "gt.txt").write_text(GOOD)
    code = main(["eval", str(tmp_path / "gt.txt"), str(est), "--json"])
    err = capfd.readouterr().err
    assert code in (0, 2)
    if code == 2:
        assert len(err.strip().splitlines()) == 1 and str(est) in err and "Traceback" not in err


SEQUENCE_FILES = ["associations.txt", "groundtruth.txt", "camera.yaml", "meta.json", "gt/objects.jsonl"]


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("pristine") / "seq"
    write_sequence(root, n=3, with_flow=False)
    return root


@settings(
    max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    name=st.sampled_from(SEQUENCE_FILES),
    offset=st.floats(0, 1),
    junk=st.binary(min_size=1, max_size=12),
    cut=st.booleans(),
)
def test_any_corrupted_sequence_file_is_read_or_refused_by_name(
    pristine: Path, tmp_path_factory, capfd, name, offset, junk, cut
):
    seq = tmp_path_factory.mktemp("h") / "seq"
    shutil.copytree(pristine, seq)
    data = (seq / name).read_bytes()
    at = int(offset * len(data))
    (seq / name).write_bytes(data[:at] + junk + (b"" if cut else data[at + len(junk) :]))
    out = seq.parent / "out"
    code = main(["preview", str(seq), "--frames", "0", "2", "-o", str(seq.parent / "p.png")])
    err = capfd.readouterr().err
    assert code in (0, 2)
    if code == 2:
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert str(seq) in err or "frame" in err
        assert not out.exists() and not (seq.parent / "p.png").exists()


# -- memory: oversized and endless inputs, in a child with a cap -------------------------------------


def _sparse(path: Path, size: int) -> None:
    with path.open("wb") as handle:
        handle.truncate(size)


def _oversized_cases(tmp: Path) -> dict[str, tuple[list[str], str]]:
    write_sequence(tmp / "seq", n=3, with_flow=False)
    (tmp / "bomb").mkdir()
    shutil.copytree(tmp / "seq", tmp / "bomb" / "seq")
    frame_file(tmp / "bomb" / "seq", "rgb", 1).write_bytes(forged_png(30000, 30000))
    _sparse(tmp / "big.txt", 10 << 30)  # 10 GiB of holes
    _sparse(tmp / "big.yaml", 10 << 30)
    (tmp / "long").mkdir()
    shutil.copytree(tmp / "seq", tmp / "long" / "seq")
    with (tmp / "long" / "seq" / "gt" / "objects.jsonl").open("r+b") as handle:
        handle.seek(0)
        handle.write(b"[")
        handle.truncate(3 << 30)  # one line of 3 GiB
    laughs = "".join(f"l{k}: &l{k} [{', '.join([f'*l{k - 1}'] * 10)}]\n" for k in range(1, 9))
    (tmp / "laughs.yaml").write_text("l0: &l0 [x, x, x, x, x, x, x, x, x, x]\n" + laughs + "name: *l8\n")
    (tmp / "grid.yaml").write_text(SUITES["huge_grid"][0])
    axis = "{range: [0.01, 10.0, 0.01]}"  # probe C12: three axes, each within its limit, 10^9 runs
    (tmp / "sweep-grid.yaml").write_text(
        f"sweep: h\nsequences: [seq]\nstrategies: [none, box_epipolar_flow]\nthresholds:\n"
        f"  box_epipolar_flow: {{epsilon_px: {axis}, l_thr1_px: {axis}, l_thr2_px: {axis}}}\n"
    )
    return {
        "eval-dev-zero": (["eval", "/dev/zero", "/dev/zero"], "/dev/zero"),
        "validate-dev-zero": (["validate", "/dev/zero"], "/dev/zero"),
        "eval-10GiB": (["eval", str(tmp / "big.txt"), str(tmp / "big.txt")], "big.txt"),
        "validate-10GiB": (["validate", str(tmp / "big.yaml")], "big.yaml"),
        "validate-laughs": (["validate", str(tmp / "laughs.yaml")], "expands"),
        "validate-grid": (["validate", str(tmp / "grid.yaml")], "limit of 10000"),
        "run-png-bomb": (
            ["run", str(tmp / "bomb" / "seq"), "-o", str(tmp / "o1"), "--detector", "none"],
            "30000x30000",
        ),
        "preview-png-bomb": (
            ["preview", str(tmp / "bomb" / "seq"), "--frames", "1", "-o", str(tmp / "p.png")],
            "30000x30000",
        ),
        "run-long-line": (["run", str(tmp / "long" / "seq"), "-o", str(tmp / "o2")], "objects.jsonl:1"),
        "sweep-10^9-grid": (
            ["sweep", str(tmp / "sweep-grid.yaml"), "-o", str(tmp / "o3")],
            "limit of 100000",
        ),
        "cmd-format-width": (  # probe C5: a 1 GB argument was built before exec refused it
            [
                "run",
                str(tmp / "seq"),
                "-o",
                str(tmp / "o4"),
                "--slam",
                "cmd",
                "--command",
                "true {sequence:>1000000000}",
            ],
            "sequence",
        ),
    }


@pytest.mark.slow  # 25 s
def test_oversized_and_endless_inputs_stay_under_300_mb(tmp_path: Path):
    cases = _oversized_cases(tmp_path)
    peaks = {}
    for name, (args, needle) in cases.items():
        code, err, peak = peak_rss_mb(args)
        assert code == 2, (name, err)
        assert len(err.strip().splitlines()) == 1 and needle in err and "Traceback" not in err, (name, err)
        peaks[name] = peak
    print("peak RSS (MB):", {name: round(peak) for name, peak in peaks.items()})
    assert max(peaks.values()) < MAX_RSS_MB, peaks
    assert not any((tmp_path / name).exists() for name in ("o1", "o2", "o3", "o4", "p.png"))


# -- every spec that validates generates ------------------------------------------------------------

coordinate = st.floats(-9, 9, allow_nan=False).map(lambda v: round(v, 2))
height = st.floats(-1, 6, allow_nan=False).map(lambda v: round(v, 2))
point2 = st.one_of(
    st.tuples(coordinate, coordinate).map(list),
    st.tuples(st.floats(-6, 6), st.floats(-4.5, 4.5)).map(lambda p: [round(v, 2) for v in p]),
)
point3 = st.tuples(coordinate, coordinate, height).map(list)
inside = st.tuples(st.floats(-6.5, 6.5), st.floats(-5, 5), st.floats(0.2, 4.3)).map(
    lambda p: [round(v, 2) for v in p]
)


@st.composite
def geometry(draw) -> dict:
    """Scenario fields with geometry, inside and outside what validation accepts."""
    spec: dict = {
        "camera": {
            "motion": draw(st.sampled_from(["static", "xyz", "rpy", "halfsphere", "robot"])),
            "position_m": draw(st.one_of(inside, inside, point3)),
            "target_m": draw(st.one_of(point3, st.just([0.0, 0.0, 0.0]))),
        },
        "intrinsics": {
            "fx": draw(st.one_of(st.floats(0.5, 5000), st.floats(15, 150), st.floats(15, 150))),
            # a full pinhole (48x36 images): fy, and a principal point on, at the edge of, or off the image
            **(
                {"fy": draw(st.floats(10, 200)), "cx": draw(st.floats(-2, 50)), "cy": draw(st.floats(-2, 38))}
                if draw(st.booleans())
                else {}
            ),
        },
        "layout": {"props": draw(st.integers(0, 60)), "rack_rows": draw(st.integers(0, 4))},
        "actors": [
            {
                "kind": draw(st.sampled_from(["person", "dog", "cat", "pig", "bird"])),
                "path": draw(st.sampled_from(["loop", "random_walk"])),
                **(
                    {"waypoints": draw(st.lists(point2, min_size=2, max_size=5))}
                    if draw(st.booleans())
                    else {}
                ),
            }
            for _ in range(draw(st.integers(0, 3)))
        ],
        "chairs": [{"position_m": draw(point2)} for _ in range(draw(st.integers(0, 2)))],
    }
    if draw(st.booleans()):
        spec["camera"]["position_m"] = [0.0, 0.0, draw(st.floats(0.5, 4.4))]  # straight above the target
        spec["camera"]["target_m"] = [0.0, 0.0, 0.0]
    return spec


@pytest.mark.render
@settings(
    max_examples=max(10, FUZZ_EXAMPLES // 10),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(spec=geometry())
def test_every_spec_that_validates_generates(tmp_path_factory, capfd, spec: dict):
    import yaml

    folder = tmp_path_factory.mktemp("gen")
    path = folder / "spec.yaml"
    path.write_text(yaml.safe_dump({"name": "g", "frames": 1, "image": {"width": 48, "height": 36}, **spec}))
    if main(["validate", str(path)]) != 0:
        err = capfd.readouterr().err
        event(f"refused: {err.split(str(path) + ': ')[-1].split(':')[0]}")
        assert len(err.strip().splitlines()) >= 1 and str(path) in err and "Traceback" not in err
        return
    capfd.readouterr()
    code = main(["generate", str(path), "-o", str(folder / "out")])
    err = capfd.readouterr().err
    # A loop that cannot be placed among the props is the one refusal validation cannot foresee.
    assert code == 0 or (code == 2 and "could not place a free walking loop" in err), err
    event("generated" if code == 0 else "no free loop")
