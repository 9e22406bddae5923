"""The camera of a real TUM-layout folder on the command line: ``--camera FILE`` or the numbers
(``--intrinsics``, ``--distortion``, ``--depth-factor``), parsed once here into a
``CameraOverride`` that ``run_sequence`` takes.

A folder given none of them is read with a guess from its name (TUM's freiburg1/2/3
calibration, else the ROS default), and the run says so in one warning line. A generated
sequence keeps its own camera: the ground truth was rendered through it, so a camera given
for one is refused (``Sequence.open``) rather than silently breaking the exact labels.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from depotbench.eval.cli.args import finite_float, positive_float

if TYPE_CHECKING:
    from depotbench.core.camera import CameraOverride

NUMBER_FLAGS = ("intrinsics", "distortion", "depth_factor")


def add_camera_options(parser: argparse.ArgumentParser, guessed: bool = True) -> None:
    """``--camera FILE``, ``--intrinsics FX FY CX CY``, ``--distortion K1 K2 P1 P2 [K3]``,
    ``--depth-factor F`` (``camera_from_args`` reads them). ``guessed``: a folder given none
    is read with a guess (``run``), else refused (``export-rosbag``); the help says which."""
    group = parser.add_argument_group(
        "camera of a real TUM folder (a generated sequence keeps its own camera.yaml)"
    )
    group.add_argument(
        "--camera",
        type=Path,
        metavar="FILE",
        help="an ORB-SLAM2/3 RGB-D settings file (Camera.fx ... DepthMapFactor, as a sequence's "
        'camera.yaml; or ORB-SLAM3\'s File.version "1.0": Camera1.fx ... RGBD.DepthMapFactor)',
    )
    group.add_argument(
        "--intrinsics",
        nargs=4,
        type=finite_float,
        metavar=("FX", "FY", "CX", "CY"),
        help="focal lengths and principal point in pixels (OpenCV: pixel centres at integers); "
        + (
            "without it a folder named like TUM's gets that sensor's calibration, else the ROS default"
            if guessed
            else "a folder without camera.yaml needs it or --camera"
        ),
    )
    group.add_argument(
        "--distortion",
        nargs="+",
        type=finite_float,
        metavar="K",
        help="with --intrinsics: K1 K2 P1 P2 [K3], OpenCV's radial-tangential model as TUM publishes "
        "it (default: none)",
    )
    group.add_argument(
        "--depth-factor",
        type=positive_float,
        metavar="F",
        help="depth PNG units per metre (TUM: 5000; a millimetre PNG: 1000)",
    )


def camera_from_args(args: argparse.Namespace) -> CameraOverride | None:
    """The camera the flags give, or None where they give none; InputError (one line naming the
    flag or the file and its key) for a bad one."""
    from depotbench.core.camera import CameraOverride, CameraSource
    from depotbench.core.errors import InputError

    given = [f"--{name.replace('_', '-')}" for name in NUMBER_FLAGS if getattr(args, name) is not None]
    if args.camera is not None:
        if given:
            raise InputError(
                f"--camera {args.camera} holds the whole camera, depth factor included; "
                f"give it or {' '.join(given)}, not both"
            )
        from depotbench.sim.camera import read_camera_file

        return read_camera_file(args.camera)
    if not given:
        return None
    distortion = args.distortion
    if distortion is not None:
        if args.intrinsics is None:
            raise InputError("--distortion belongs with a calibration: give --intrinsics FX FY CX CY too")
        if len(distortion) not in (4, 5):
            raise InputError(f"--distortion: give K1 K2 P1 P2 [K3] (4 or 5 numbers), got {len(distortion)}")
        distortion = (*distortion, 0.0)[:5]  # OpenCV's k3 is 0 when left out
    try:
        return CameraOverride(
            pinhole=None if args.intrinsics is None else tuple(args.intrinsics),
            distortion=None if distortion is None else tuple(distortion),
            depth_factor=args.depth_factor,
            source=CameraSource.FLAGS,
            origin=" ".join(given),
        )
    except ValueError as exc:
        raise InputError(str(exc)) from None
