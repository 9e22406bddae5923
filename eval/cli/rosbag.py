"""``depotbench export-rosbag``: a sequence as a ROS 2 bag for ``ros2 bag play``.

Free of heavy imports (``depotbench --help`` builds this parser): the choices are named here
and ``tests/test_rosbag.py`` holds them equal to ``depotbench.eval.export.rosbag``'s.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from depotbench.core.errors import EnvironmentProblem
from depotbench.core.text_table import Column, render
from depotbench.eval.cli.camera import add_camera_options, camera_from_args
from depotbench.eval.cli.conventions import add_json, print_result

STORAGES = ("mcap", "sqlite3")
"""``depotbench.eval.export.rosbag.BagStorage``."""
DEPTHS = ("m", "mm", "raw")
"""``depotbench.eval.export.rosbag.DepthUnit``."""
DEFAULT_NAMESPACE = "/camera"
"""``depotbench.eval.export.rosbag.DEFAULT_NAMESPACE``."""
ROS_EXTRA_MISSING = "export-rosbag needs the ros extra: pip install 'depotbench[ros]'"
"""``rosbags`` serves this one command: it and its four dependencies (18 MB) are an extra."""


def add_export_rosbag(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export-rosbag",
        help="a sequence as a ROS 2 bag (MCAP or SQLite) for ros2 bag play: images, camera info, "
        "true poses as TF and path, ground-truth boxes",
    )
    p.add_argument("sequence", type=Path, help="a generated sequence folder or a real TUM RGB-D folder")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="BAG", help="the bag folder to write")
    p.add_argument(
        "--storage", choices=STORAGES, default="mcap", help="rosbag2 storage plugin (default: mcap)"
    )
    p.add_argument(
        "--depth",
        choices=DEPTHS,
        default="m",
        help="m: 32FC1 metres, NaN = none (REP 118, what every ROS node reads; default); mm: 16UC1 "
        "millimetres, 0 = none (REP 118 raw, rounded to 1 mm); raw: 16UC1 depth-PNG values "
        "(metres x depth scale, 5000 for TUM) for nodes given that factor, e.g. ORB-SLAM3's DepthMapFactor",
    )
    p.add_argument(
        "--detections",
        action="store_true",
        help="also write the ground-truth 2D boxes as vision_msgs/Detection2DArray (generated sequences)",
    )
    p.add_argument(
        "--namespace",
        default=DEFAULT_NAMESPACE,
        help=f"namespace of the camera's topics and prefix of its frames (default: {DEFAULT_NAMESPACE})",
    )
    p.add_argument("--compress", action="store_true", help="zstd-compress the MCAP chunks (mcap only)")
    p.add_argument("--overwrite", action="store_true", help="replace a bag depotbench wrote")
    add_camera_options(p, guessed=False)
    add_json(p, "the bag's path, storage, size, frames and each topic's type and message count")
    p.set_defaults(handler=_cmd_export_rosbag)


def _cmd_export_rosbag(args: argparse.Namespace) -> int:
    try:
        from depotbench.eval.export.rosbag import write_bag
    except ModuleNotFoundError as exc:
        if (exc.name or "").partition(".")[0] != "rosbags":
            raise
        raise EnvironmentProblem(ROS_EXTRA_MISSING) from None

    started = time.perf_counter()
    summary = write_bag(
        args.sequence,
        args.output,
        storage=args.storage,
        depth=args.depth,
        detections=args.detections,
        namespace=args.namespace,
        compress=args.compress,
        overwrite=args.overwrite,
        camera=camera_from_args(args),
    )
    messages = sum(t.count for t in summary.topics)
    size_mb = summary.size_bytes / 1e6
    head = f"{summary.storage.value}, {summary.frames} frames, {messages} messages, {size_mb:.1f} MB"
    lines = [f"wrote {summary.path} ({head})"]
    columns = [Column("topic", "left"), Column("type", "left"), Column("messages")]
    lines.append(render(columns, [[t.topic, t.msgtype, str(t.count)] for t in summary.topics], indent=2))
    lines += [f"note: {note}" for note in summary.notes]
    lines.append(f"play it with: ros2 bag play {summary.path}")
    result = {
        "bag": summary.path,
        "storage": summary.storage.value,
        "depth": summary.depth.value,
        "frames": summary.frames,
        "messages": messages,
        "bytes": summary.size_bytes,
        "topics": [{"topic": t.topic, "type": t.msgtype, "count": t.count} for t in summary.topics],
        "notes": list(summary.notes),
        "seconds": time.perf_counter() - started,
    }
    print_result(args, result, "\n".join(lines))
    return 0
