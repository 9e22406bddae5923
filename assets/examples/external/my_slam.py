#!/usr/bin/env python3
"""A small RGB-D visual odometry to copy as the start of your own tracker.

It speaks depotbench's external-tracker protocol (docs/external-trackers.md) by hand,
with nothing but NumPy and OpenCV, so every file it reads and writes is visible here:

    my_slam.py SEQUENCE ASSOCIATIONS SETTINGS DETECTIONS TRAJECTORY KEYPOINTS \
        [--box-margin PX] [--features N]

Per frame: ORB keypoints; those inside a ``dynamic`` box (grown by ``--box-margin``) are
rejected; the rest are matched to the last tracked frame, whose matched keypoints are
lifted to 3D with its depth; PnP with RANSAC gives the motion between the two frames,
and chaining the motions gives the camera's pose. No map, no keyframes, no loop closure:
it drifts, and that is where your own system begins.

In a sweep spec:

    trackers:
      - name: my_slam
        command: ./my_slam.py {sequence} {associations} {settings} {detections}
          {trajectory} {keypoints} --box-margin {box_margin}
        parameters: {box_margin: 0}

(in a spec beside this file: a program's path is relative to the spec; it runs on the
``python3`` first in ``PATH``, which needs numpy and opencv-python-headless).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

MIN_INLIERS = 12
"""Fewer PnP inliers than this and a frame counts as lost (it gets no trajectory line)."""


def read_camera(path: Path) -> tuple[np.ndarray, float]:
    """The intrinsic matrix K and the depth PNG units per metre, from ORB-SLAM-style settings
    (``Camera.fx: 525.0`` lines under ``%YAML:1.0``), read as ORB-SLAM reads them."""
    settings = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not settings.isOpened():
        sys.exit(f"my_slam: cannot read the settings {path}")

    def value(key: str) -> float:
        node = settings.getNode(key)
        if node.empty():
            sys.exit(f"my_slam: {path} has no {key}")
        return node.real()

    fx, fy, cx, cy = (value(f"Camera.{k}") for k in ("fx", "fy", "cx", "cy"))
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), value("DepthMapFactor")


def read_associations(path: Path) -> list[tuple[str, Path, Path]]:
    """(RGB timestamp as written, RGB file, depth file) per frame, in order. The
    timestamp is kept as text: the trajectory and keypoint lines repeat it exactly."""
    frames = []
    for line in path.read_text().splitlines():
        fields = line.split()
        if fields and not fields[0].startswith("#"):
            frames.append((fields[0], path.parent / fields[1], path.parent / fields[3]))
    return frames


def read_dynamic_boxes(path: Path) -> dict[float, list[tuple[float, float, float, float]]]:
    """The boxes of ``dynamic`` prior per frame timestamp: ``t x0 y0 x1 y1 prior confidence
    class``, where the class (the rest of the line) may hold spaces. Boxes are in pixel-edge
    coordinates: pixel column u covers [u, u+1)."""
    boxes: dict[float, list[tuple[float, float, float, float]]] = {}
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        t, x0, y0, x1, y1, prior, _confidence, _class = line.split(maxsplit=7)
        if prior == "dynamic":  # a real system might also weigh the confidence and class
            boxes.setdefault(float(t), []).append((float(x0), float(y0), float(x1), float(y1)))
    return boxes


def outside_boxes(points: np.ndarray, boxes: list, margin: float) -> np.ndarray:
    """True for the keypoints outside every box grown by ``margin`` px. A keypoint's position
    has pixel centres at integers, so its pixel-edge coordinate is position + 0.5."""
    keep = np.ones(len(points), bool)
    edge = points + 0.5
    for x0, y0, x1, y1 in boxes:
        inside = (
            (edge[:, 0] >= x0 - margin)
            & (edge[:, 0] < x1 + margin)
            & (edge[:, 1] >= y0 - margin)
            & (edge[:, 1] < y1 + margin)
        )
        keep &= ~inside
    return keep


def backproject(points: np.ndarray, depth_m: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3D points in the camera frame (x right, y down, z forward) of the keypoints with a
    depth reading, and which keypoints those are."""
    cols = np.clip(np.rint(points[:, 0]).astype(int), 0, depth_m.shape[1] - 1)
    rows = np.clip(np.rint(points[:, 1]).astype(int), 0, depth_m.shape[0] - 1)
    z = depth_m[rows, cols]
    valid = z > 0  # 0: no reading
    x = (points[valid, 0] - k[0, 2]) * z[valid] / k[0, 0]
    y = (points[valid, 1] - k[1, 2]) * z[valid] / k[1, 1]
    return np.column_stack([x, y, z[valid]]), valid


def relative_motion(previous, current, k: np.ndarray) -> np.ndarray | None:
    """The 4x4 transform from the previous camera's frame to the current one, or None.

    ``previous`` and ``current`` are (keypoints (N, 2), descriptors, depth in metres)."""
    if len(previous[1]) == 0 or len(current[1]) == 0:  # OpenCV's matcher refuses an empty set
        return None
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)  # mutual best matches only
    matches = [m for m in matcher.match(previous[1], current[1]) if m.distance < 64]
    if len(matches) < MIN_INLIERS:
        return None
    before = previous[0][[m.queryIdx for m in matches]]
    after = current[0][[m.trainIdx for m in matches]]
    points_3d, valid = backproject(before, previous[2], k)
    if valid.sum() < MIN_INLIERS:
        return None
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        points_3d, after[valid], k, None, reprojectionError=2.0, iterationsCount=200
    )
    if not ok or inliers is None or len(inliers) < MIN_INLIERS:
        return None
    motion = np.eye(4)
    motion[:3, :3], motion[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    return motion


def tum_line(timestamp: str, world_from_camera: np.ndarray) -> str:
    """``timestamp tx ty tz qx qy qz qw``; the quaternion from the rotation's axis-angle."""
    rvec = cv2.Rodrigues(world_from_camera[:3, :3])[0].ravel()
    angle = float(np.linalg.norm(rvec))
    axis = rvec / angle if angle > 0 else np.zeros(3)
    q = (*(axis * np.sin(angle / 2)), np.cos(angle / 2))
    values = (*world_from_camera[:3, 3], *q)
    return timestamp + "".join(f" {v:.9f}" for v in values) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description="A small RGB-D visual odometry (depotbench example).")
    for name in ("sequence", "associations", "settings", "detections", "trajectory", "keypoints"):
        parser.add_argument(name, type=Path)
    parser.add_argument("--box-margin", type=float, default=0.0, help="grow dynamic boxes by this (px)")
    parser.add_argument("--features", type=int, default=1000, help="ORB keypoints per frame")
    args = parser.parse_args()

    k, depth_factor = read_camera(args.settings)
    frames = read_associations(args.associations)
    boxes = read_dynamic_boxes(args.detections)
    # A 15 px patch and a FAST threshold of 10 (OpenCV: 31 and 20) leave small images
    # enough keypoints: on 160x120 frames the defaults found a quarter as many.
    orb = cv2.ORB_create(nfeatures=args.features, edgeThreshold=15, patchSize=15, fastThreshold=10)
    world_from_camera = np.eye(4)  # the first frame is the world: the bench aligns trajectories
    last = None  # (keypoints, descriptors, depth) of the last tracked frame

    # Both files are written as frames are done: a crash leaves what was tracked so far.
    with args.trajectory.open("w") as trajectory, args.keypoints.open("w") as decisions:
        trajectory.write("# timestamp tx ty tz qx qy qz qw\n")
        decisions.write("# depotbench keypoints 1\n# timestamp x y kept [reason]\n")
        for done, (stamp, rgb_path, depth_path) in enumerate(frames, start=1):
            gray = cv2.imread(str(rgb_path), cv2.IMREAD_GRAYSCALE)
            depth_m = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED).astype(np.float64) / depth_factor
            keypoints, descriptors = orb.detectAndCompute(gray, None)
            if descriptors is None:  # OpenCV's answer for no keypoints at all
                descriptors = np.zeros((0, 32), np.uint8)
            points = np.array([kp.pt for kp in keypoints], np.float64).reshape(-1, 2)
            kept = outside_boxes(points, boxes.get(float(stamp), []), args.box_margin)

            # Every keypoint extracted, kept (1) or rejected (0) with the reason: the bench
            # scores these decisions against the exact per-pixel ground truth.
            for (x, y), keep in zip(points, kept, strict=True):
                decisions.write(f"{stamp} {x:.3f} {y:.3f} {'1' if keep else '0 box'}\n")

            current = (points[kept], descriptors[kept], depth_m)
            motion = np.eye(4) if last is None else relative_motion(last, current, k)
            if motion is not None:  # tracked: chain the motion, match the next frame to this one
                world_from_camera = world_from_camera @ np.linalg.inv(motion)
                trajectory.write(tum_line(stamp, world_from_camera))
                last = current
            print(done, file=sys.stderr, flush=True)  # frames done: the bench's progress bar


if __name__ == "__main__":
    main()
