"""A stand-in for a user's SLAM program, for the tests of the external-tracker protocol
(docs/external-trackers.md): fast, deterministic, and able to misbehave on request.

It "tracks" by reading the sequence's ground truth and perturbing each position by a
seeded offset of ``noise_m``; it "extracts" a grid of keypoints and rejects those inside
a dynamic box grown by ``margin_px``. Its parameters come from ``{parameters}``; ``mode``
selects a misbehaviour: ``hang``, ``flood`` (1 GB on stdout), ``fork`` (a child that
sleeps forever), ``bad_trajectory``, ``nan_keypoint``, ``outside_keypoint``, ``exit3``.
``run_noise_m`` adds noise drawn anew on every run (from the OS), for a program whose runs
differ as a multi-threaded SLAM system's do. ``tuned_seeds`` (``1;2;3``) names seeds where
``tuned_noise_m`` replaces ``noise_m``: a program fitted to those sequences.

    oracle_slam.py SEQUENCE DETECTIONS PARAMETERS TRAJECTORY KEYPOINTS
"""

import json
import os
import random
import subprocess
import sys
import time
import zlib
from pathlib import Path


def main() -> int:
    sequence, detections, parameters, trajectory, keypoints = map(Path, sys.argv[1:6])
    params = json.loads(parameters.read_text())
    mode = params.get("mode", "ok")
    if mode == "hang":
        time.sleep(3600)
    if mode == "flood":  # then tracks as usual
        chunk = b"x" * (1 << 20) + b"\n"
        for _ in range(1024):
            sys.stdout.buffer.write(chunk)
    if mode == "fork":
        subprocess.Popen([sys.executable, "-c", "import time; time.sleep(3600)"])
    if mode == "exit3":
        print("giving up: a deliberate failure", file=sys.stderr)
        return 3
    noise, margin = float(params.get("noise_m", 0.0)), float(params.get("margin_px", 0.0))
    run_noise = float(params.get("run_noise_m", 0.0))
    if "tuned_seeds" in params:  # a masked copy of the sequence has no meta.json
        seed = json.loads((sequence / "meta.json").read_text()).get("seed")
        if str(seed) in str(params["tuned_seeds"]).split(";"):
            noise = float(params["tuned_noise_m"])
    draw = random.Random(os.urandom(16))
    boxes = _boxes(detections)
    width, height = _size(sequence / "camera.yaml")
    lines = []
    frames = 0
    with (sequence / "groundtruth.txt").open() as gt, keypoints.open("w") as out:
        out.write("# depotbench keypoints 1\n# timestamp x y kept [reason]\n")
        for line in gt:
            if line.startswith("#") or not line.strip():
                continue
            stamp, *pose = line.split()
            offset = (zlib.crc32(stamp.encode()) % 1000 / 1000.0 - 0.5) * 2 * noise
            x, y, z = (float(v) for v in pose[:3])
            x += draw.gauss(0.0, run_noise) if run_noise else 0.0
            lines.append(f"{stamp} {x + offset!r} {y - offset!r} {z!r} {' '.join(pose[3:])}\n")
            for px in range(8, width, 16):
                for py in range(8, height, 16):
                    inside = any(
                        x0 - margin <= px < x1 + margin and y0 - margin <= py < y1 + margin
                        for t, x0, y0, x1, y1, prior in boxes
                        if t == stamp and prior == "dynamic"
                    )
                    out.write(f"{stamp} {px}.0 {py}.0 {0 if inside else 1}{' box' if inside else ''}\n")
            frames += 1
            print(frames, file=sys.stderr, flush=True)
        if mode == "nan_keypoint":
            out.write(f"{stamp} nan 3.0 1\n")
        if mode == "outside_keypoint":
            out.write(f"{stamp} {width + 5}.0 3.0 1\n")
    if mode == "bad_trajectory":
        lines[1] = "this is not a pose\n"
    trajectory.write_text("# oracle\n" + "".join(lines))
    if mode == "fork":
        time.sleep(0.2)  # exits while its child sleeps on
    return 0


def _boxes(path: Path) -> list[tuple]:
    out = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        stamp, x0, y0, x1, y1, prior, _confidence, _name = line.split(maxsplit=7)
        out.append((stamp, float(x0), float(y0), float(x1), float(y1), prior))
    return out


def _size(camera: Path) -> tuple[int, int]:
    values = dict(line.split(":", 1) for line in camera.read_text().splitlines() if ":" in line)
    return int(values["Camera.width"]), int(values["Camera.height"])


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
