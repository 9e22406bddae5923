"""A stand-in for a user's SLAM program that writes a map (``{map}``), for the tests of the
external-tracker protocol: its trajectory is the sequence's ground truth expressed in its own
world, the first frame's camera (as a SLAM system's world is), and its map is the first
frame's depth back-projected in that world, every 4th pixel, as an ASCII PLY with colours.

    map_slam.py SEQUENCE TRAJECTORY MAP
"""

import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation


def main() -> int:
    sequence, trajectory, map_path = map(Path, sys.argv[1:4])
    values = dict(
        line.split(":", 1) for line in (sequence / "camera.yaml").read_text().splitlines() if ":" in line
    )
    fx, fy, cx, cy = (float(values[f"Camera.{k}"]) for k in ("fx", "fy", "cx", "cy"))
    scale = float(values["DepthMapFactor"])
    stamps, poses = [], []
    for line in (sequence / "groundtruth.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        stamp, *numbers = line.split()
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_quat([float(v) for v in numbers[3:7]]).as_matrix()
        pose[:3, 3] = [float(v) for v in numbers[:3]]
        stamps.append(stamp)
        poses.append(pose)
    world = np.linalg.inv(poses[0])  # this program's world: the first camera
    lines = ["# map_slam\n"]
    for stamp, pose in zip(stamps, poses, strict=True):
        mine = world @ pose
        q = Rotation.from_matrix(mine[:3, :3]).as_quat()
        lines.append(f"{stamp} {' '.join(repr(float(v)) for v in (*mine[:3, 3], *q))}\n")
    trajectory.write_text("".join(lines))
    first = (sequence / "associations.txt").read_text().split("\n", 1)[0].split()
    rgb = cv2.imread(str(sequence / first[1]))[:, :, ::-1]
    depth = cv2.imread(str(sequence / first[3]), cv2.IMREAD_UNCHANGED).astype(np.float64) / scale
    v, u = np.mgrid[0 : depth.shape[0] : 4, 0 : depth.shape[1] : 4]
    z = depth[v, u]
    keep = z > 0
    u, v, z = u[keep], v[keep], z[keep]
    points = np.column_stack([(u - cx) / fx * z, (v - cy) / fy * z, z])  # the first camera's frame
    colours = rgb[v, u]
    header = (
        f"ply\nformat ascii 1.0\nelement vertex {len(points)}\nproperty float x\nproperty float y\n"
        "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    body = "".join(
        f"{x:.6f} {y:.6f} {zz:.6f} {r} {g} {b}\n"
        for (x, y, zz), (r, g, b) in zip(points, colours, strict=True)
    )
    map_path.write_text(header + body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
