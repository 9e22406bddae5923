"""ORB-SLAM3 in a process of its own: ``python -m depotbench.eval.trackers.orbslam3_worker REQUEST.json``.

ORB-SLAM3 (the ``pyorbslam3`` wheel) is GPL-3 and runs only here, never in the
bench's own process. A fresh process per run also contains its faults: it calls
``exit()`` on a vocabulary it cannot read, leaks ~70 MB per instance, and prints
to the C stdout, which goes to ``orbslam3.log`` beside the results.

The request (JSON) names ``vocabulary``, ``settings``, ``sequence``, ``out`` and ``pace``
(each frame takes at least pace x the gap to the next timestamp, as ORB-SLAM3's rgbd_tum
example waits; 0: back to back). Each frame becomes one line of ``out/frames.jsonl``:
timestamp, ORB-SLAM3's state, the pose (world_from_camera, the first frame's camera as
world) when it has one, the milliseconds ``track_rgbd`` took and the number of tracked
map points. The map points
seen in tracked frames, each where it stood when last seen, go to ``out/map_points.npy``
(its sparse map, for ``--map``). Progress goes to stderr as one frame count per line.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def _quiet_native_stdout(log: Path) -> None:
    """ORB-SLAM3 prints with std::cout on file descriptor 1: send that to the log."""
    sys.stdout.flush()
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.close(fd)


def _gap(times: list[float], i: int) -> float:
    """rgbd_tum.cc's wait for frame ``i``: the gap to the next timestamp (the last frame: to
    the one before)."""
    if i + 1 < len(times):
        return times[i + 1] - times[i]
    return times[i] - times[i - 1] if i else 0.0


def main(request_path: str) -> int:
    from depotbench.core.camera import Intrinsics
    from depotbench.core.processes import exit_with_parent
    from depotbench.sim.sequence import Sequence

    exit_with_parent(os.getppid())
    request = json.loads(Path(request_path).read_text(encoding="utf-8"))
    out = Path(request["out"])
    _quiet_native_stdout(out / "orbslam3.log")
    import pyorbslam3

    given = request["intrinsics"]
    intrinsics = None if given is None else Intrinsics(**{**given, "distortion": tuple(given["distortion"])})
    sequence = Sequence.open(request["sequence"], intrinsics=intrinsics)
    slam = pyorbslam3.Slam(
        request["vocabulary"], request["settings"], pyorbslam3.Sensor.RGBD, use_viewer=False
    )
    pace = float(request.get("pace", 0.0))
    times = [frame.timestamp_s for frame in sequence.frames]
    lines, seen = [], []
    for i in range(len(sequence)):
        rgb = sequence.rgb(i)  # RGB order, as the settings' Camera.RGB: 1 says
        depth = sequence.depth_raw(i).astype("float32")  # stored units; DepthMapFactor scales them
        timestamp = times[i]
        started = time.perf_counter()
        result = slam.track_rgbd(rgb, depth, timestamp)
        elapsed_ms = (time.perf_counter() - started) * 1e3
        pose = result.pose_wc.tolist() if result.pose_valid and result.pose_wc is not None else None
        if pose is not None:
            seen.append(np.asarray(slam.tracked_map_points(), dtype=np.float32).reshape(-1, 3))
        lines.append(
            json.dumps(
                {
                    "timestamp_s": timestamp,
                    "state": result.state.name,
                    "pose": pose,
                    "track_ms": elapsed_ms,
                    "tracked_points": int(result.num_tracked_points),
                }
            )
        )
        print(i + 1, file=sys.stderr, flush=True)
        if pace > 0:
            left = pace * _gap(times, i) - (time.perf_counter() - started)
            if left > 0:
                time.sleep(left)
    slam.save_keyframe_trajectory_tum(str(out / "keyframes.txt"))
    if seen:  # a point seen in many frames once; one BA moved keeps each position it had
        points = np.unique(np.concatenate(seen), axis=0)
        np.save(out / "map_points.npy", points[np.isfinite(points).all(axis=1)])
    slam.shutdown()
    staged = out / "frames.jsonl.partial"
    staged.write_text("\n".join(lines) + "\n", encoding="utf-8")
    os.replace(staged, out / "frames.jsonl")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
