"""A sequence as a ROS 2 bag, so that ROS 2 nodes (ORB-SLAM3 and RTAB-Map wrappers, Nav2,
rviz) can be fed the bench's sequences with ``ros2 bag play`` (docs/rosbag.md).

Written with the pure-Python ``rosbags`` library: no ROS installation is needed. What goes in:

- colour as ``sensor_msgs/Image`` (rgb8) and depth as ``sensor_msgs/Image`` in one of the
  ``DEPTH_FORMS`` (32FC1 metres by default: REP 118's canonical form, the only one every
  consumer must read), each with its ``sensor_msgs/CameraInfo``; header stamps are the
  frames' timestamps, ``frame_id`` the camera's optical frame (depth is registered to colour);
- the true pose, exactly ``groundtruth.txt``'s rows at their own timestamps: as TF on ``/tf``
  (world -> optical frame), as ``geometry_msgs/PoseStamped`` per row, and as one latched
  ``nav_msgs/Path``; a static TF from the optical frame to a REP 103 body frame;
- optionally the ground-truth 2D boxes as ``vision_msgs/Detection2DArray``.

The bag is staged beside its target and swapped into place when complete (``StagedOutput``),
so it never half-exists.
"""

from __future__ import annotations

import heapq
import os
import re
import struct
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from depotbench.core.camera import FALLBACKS, CameraOverride, CameraSource
from depotbench.core.errors import InputError
from depotbench.core.output import OutputKind, StagedOutput
from depotbench.core.progress import progress_bar
from depotbench.core.version import package_version
from depotbench.sim.ground_truth import ObjectState
from depotbench.sim.sequence import Sequence, pose_matrix
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore
from scipy.spatial.transform import Rotation

TYPESTORE = Stores.ROS2_HUMBLE
"""Message definitions of ROS 2 Humble, the LTS most ROS SLAM wrappers target; the types used
here are unchanged up to Kilted, so Jazzy plays the bag too."""
BAG_VERSION = 8
"""rosbag2 metadata version 8: version 9 writes each topic's QoS as a YAML list, which Humble's
reader (it expects a string) cannot parse."""
WORLD_FRAME = "world"
GROUND_TRUTH_NAMESPACE = "/ground_truth"
DEFAULT_NAMESPACE = "/camera"
INFINITE = QosTime(2147483647, 4294967295)
"""The duration ``ros2 bag record`` stores for an unset deadline, lifespan or lease."""

OPTICAL_FROM_BODY = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
"""Rotation taking a REP 103 body frame's axes (x forward, y left, z up) into the optical
frame's (x right, y down, z forward): the body's forward axis is the optical z."""


class BagStorage(StrEnum):
    """rosbag2's storage plugins: MCAP (ROS 2's default since Iron) or SQLite (Humble's)."""

    MCAP = "mcap"
    SQLITE3 = "sqlite3"


STORAGE_PLUGINS = {BagStorage.MCAP: StoragePlugin.MCAP, BagStorage.SQLITE3: StoragePlugin.SQLITE3}


class DepthUnit(StrEnum):
    METRES = "m"
    MILLIMETRES = "mm"
    RAW = "raw"


@dataclass(frozen=True)
class DepthForm:
    """How depth images are encoded in the bag, and the topic REP 118 puts them on."""

    encoding: str
    topic: str
    meaning: str
    convert: Callable[[np.ndarray, float, Path], np.ndarray]


def _metres(raw: np.ndarray, scale: float, where: Path) -> np.ndarray:
    """float32 metres, as ``Sequence.depth_m`` computes them; no reading is NaN (REP 117/118:
    a 0.0 would be a point at the camera centre to depth_image_proc). Lossless: rounding
    ``value x scale`` gives the PNG back, since float32 holds 16-bit values exactly enough."""
    depth = raw.astype(np.float32) / np.float32(scale)
    depth[raw == 0] = np.nan
    return depth.astype("<f4", copy=False)


def _millimetres(raw: np.ndarray, scale: float, where: Path) -> np.ndarray:
    """uint16 millimetres, REP 118's OpenNI raw form: TUM's 0.2 mm steps round to 1 mm, and a
    reading never rounds to 0 (which means none)."""
    mm = np.rint(raw.astype(np.float64) * (1000.0 / scale))
    if mm.size and mm.max() > np.iinfo(np.uint16).max:
        raise InputError(
            f"{where}: depth {mm.max() / 1000:.3f} m exceeds 16UC1 millimetres' 65.535 m; use --depth m"
        )
    mm[(raw > 0) & (mm == 0)] = 1
    return mm.astype("<u2")


def _raw(raw: np.ndarray, scale: float, where: Path) -> np.ndarray:
    return raw.astype("<u2", copy=False)


DEPTH_FORMS: dict[DepthUnit, DepthForm] = {
    DepthUnit.METRES: DepthForm(
        "32FC1", "image", "32FC1 metres along z, NaN = no reading (REP 118)", _metres
    ),
    DepthUnit.MILLIMETRES: DepthForm(
        "16UC1", "image_raw", "16UC1 millimetres along z, 0 = no reading (REP 118 raw)", _millimetres
    ),
    DepthUnit.RAW: DepthForm(
        "16UC1",
        "image_raw",
        "16UC1 depth PNG values, metres x depth_scale, 0 = no reading (not REP 118: give nodes the factor)",
        _raw,
    ),
}

VISION_MSGS = {
    "vision_msgs/msg/Point2D": "float64 x\nfloat64 y\n",
    "vision_msgs/msg/Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "vision_msgs/msg/BoundingBox2D": "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": (
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n"
    ),
    "vision_msgs/msg/Detection2D": (
        "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
        "vision_msgs/BoundingBox2D bbox\nstring id\n"
    ),
    "vision_msgs/msg/Detection2DArray": "std_msgs/Header header\nvision_msgs/Detection2D[] detections\n",
}
"""vision_msgs 4.1 (Humble's and Jazzy's) as far as Detection2DArray needs: rosbags ships no
vision_msgs, so the definitions are registered from their text."""

NAME_PATTERN = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")
"""A ROS 2 namespace: absolute, tokens of letters, digits and underscores, none starting with a digit."""
TOPIC_MAX_CHARS = 255 - 8
"""rmw's ``RMW_TOPIC_MAX_NAME_LENGTH``: a fully qualified topic name of more characters cannot
be created (DDS topic names end at 256, and ROS 2 keeps 8 for its ``rt/`` style prefixes)."""
TIME_MAX_S = 2**31
"""``builtin_interfaces/msg/Time`` holds ``int32 sec`` (and ``uint32 nanosec``): header stamps
from 0 up to, not including, 2^31 s (2038-01-19)."""
DATA_STEM = "bag"
"""The data file's name (``bag.mcap``) where the bag folder's own name leaves no room for the
suffix: rosbags names the file after its folder, which fails for names of 251-255 bytes."""


def _qos(durability: QosDurability, depth: int) -> list[Qos]:
    """Reliable, which any subscriber accepts (best-effort publishers fail reliable subscribers)."""
    return [
        Qos(
            QosHistory.KEEP_LAST,
            depth,
            QosReliability.RELIABLE,
            durability,
            INFINITE,
            INFINITE,
            QosLiveliness.AUTOMATIC,
            INFINITE,
            False,
        )
    ]


STREAM = _qos(QosDurability.VOLATILE, 10)
LATCHED = _qos(QosDurability.TRANSIENT_LOCAL, 1)
"""Transient local, as tf2 publishes /tf_static: a node that starts late still gets it."""


@dataclass(frozen=True)
class TopicNames:
    """Every topic and frame name of a bag, derived from the camera's namespace."""

    namespace: str
    color_image: str
    color_info: str
    depth_image: str
    depth_info: str
    detections: str
    optical_frame: str
    body_frame: str
    tf: str = "/tf"
    tf_static: str = "/tf_static"
    pose: str = f"{GROUND_TRUTH_NAMESPACE}/pose"
    path: str = f"{GROUND_TRUTH_NAMESPACE}/path"

    @classmethod
    def under(cls, namespace: str, depth: DepthForm) -> TopicNames:
        if len(namespace) > TOPIC_MAX_CHARS:  # before the pattern: a 5000-character name is not echoed
            raise InputError(
                f"--namespace of {len(namespace)} characters makes topics ROS 2 cannot create "
                f"(at most {TOPIC_MAX_CHARS} characters a topic); give one like /camera"
            )
        if not NAME_PATTERN.fullmatch(namespace) or namespace == GROUND_TRUTH_NAMESPACE:
            raise InputError(
                f"namespace {namespace!r} is not a ROS 2 namespace like /camera "
                f"(absolute, letters, digits and _, and not {GROUND_TRUTH_NAMESPACE})"
            )
        prefix = namespace.strip("/").replace("/", "_")
        names = cls(
            namespace=namespace,
            color_image=f"{namespace}/color/image_raw",
            color_info=f"{namespace}/color/camera_info",
            depth_image=f"{namespace}/depth/{depth.topic}",
            depth_info=f"{namespace}/depth/camera_info",
            detections=f"{namespace}/detections",
            optical_frame=f"{prefix}_color_optical_frame",
            body_frame=f"{prefix}_link",
        )
        longest = max(names.topics, key=len)
        if len(longest) > TOPIC_MAX_CHARS:
            raise InputError(
                f"--namespace of {len(namespace)} characters makes the topic {longest[len(namespace) :]!r} "
                f"{len(longest)} characters long; ROS 2 creates at most {TOPIC_MAX_CHARS}, so give at "
                f"most {TOPIC_MAX_CHARS - len(longest) + len(namespace)}"
            )
        return names

    @property
    def topics(self) -> tuple[str, ...]:
        return (
            self.color_image,
            self.color_info,
            self.depth_image,
            self.depth_info,
            self.detections,
            self.tf,
            self.tf_static,
            self.pose,
            self.path,
        )


@dataclass(frozen=True)
class TopicCount:
    topic: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class BagSummary:
    """What ``write_bag`` wrote."""

    path: Path
    storage: BagStorage
    depth: DepthUnit
    frames: int
    topics: tuple[TopicCount, ...]
    size_bytes: int
    notes: tuple[str, ...]
    """What was left out and why (a real TUM folder without ground truth, say)."""


E = TypeVar("E", bound=StrEnum)


def parse_choice(kind: type[E], value: E | str, what: str) -> E:
    """An API caller's string as the enum, refused in one line naming the choices."""
    try:
        return kind(value)
    except ValueError:
        choices = ", ".join(item.value for item in kind)
        raise InputError(f"{what} {value!r} is not one of {choices}") from None


def stamp_ns(timestamp_s: float) -> int:
    """Nanoseconds of a TUM timestamp, exact for the files' 6 decimals: the float is within
    0.12 us of the written value at 1.3e9 s, so rounding to the microsecond recovers it."""
    return round(timestamp_s * 1e6) * 1000


def stamps_ns(timestamps_s: np.ndarray) -> np.ndarray:
    """``stamp_ns`` of each timestamp, as int64 (``np.rint`` rounds half to even, as ``round``)."""
    return np.rint(np.asarray(timestamps_s, dtype=np.float64) * 1e6).astype(np.int64) * 1000


def path_cdr(
    ns: int, frame: str, pose_ns: np.ndarray, positions_m: np.ndarray, quats_xyzw: np.ndarray
) -> memoryview:
    """A ``nav_msgs/msg/Path`` in little-endian CDR, as ``serialize_cdr`` writes it, from arrays.

    CDR aligns each primitive to its size, counted from the end of the 4-byte encapsulation
    header. Each PoseStamped is ``int32 sec, uint32 nanosec, string frame_id`` (a uint32
    length with the NUL, the bytes, the NUL), padding to 8, then 7 float64: a fixed stride when
    the first element starts at a multiple of 8, as it does after ``world``'s header (24 bytes
    in). The test holds this against rosbags' own serializer."""
    name = frame.encode() + b"\0"
    head = struct.pack("<iII", *divmod(ns, 1_000_000_000), len(name)) + name
    head += bytes(-len(head) % 4) + struct.pack("<I", len(pose_ns))
    doubles = 12 + len(name) + (-(12 + len(name)) % 8)
    size = doubles + 56
    if len(head) % 8 or size % 8:  # another frame name would need per-element padding
        raise ValueError(f"path_cdr: frame {frame!r} gives no fixed stride")
    element = np.dtype(
        {
            "names": ["sec", "nanosec", "length", "frame", "position", "quat"],
            "formats": ["<i4", "<u4", "<u4", f"S{len(name)}", ("<f8", 3), ("<f8", 4)],
            "offsets": [0, 4, 8, 12, doubles, doubles + 24],
            "itemsize": size,
        }
    )
    head = b"\x00\x01\x00\x00" + head  # CDR little-endian, no options
    message = np.zeros(len(head) + len(pose_ns) * size, np.uint8)  # one buffer, written in place
    message[: len(head)] = np.frombuffer(head, np.uint8)
    poses = message[len(head) :].view(element)
    poses["sec"], poses["nanosec"] = np.divmod(pose_ns, 1_000_000_000)
    poses["length"] = len(name)
    poses["frame"] = name
    poses["position"] = positions_m
    poses["quat"] = quats_xyzw
    return message.data


class Event(IntEnum):
    """What the bag records at one instant, in this order when instants tie."""

    POSE = 0
    COLOR = 1
    DEPTH = 2
    DETECTIONS = 3


def _pose_events(pose_ns: np.ndarray) -> Iterator[tuple[int, Event, int]]:
    for j in range(len(pose_ns)):
        yield int(pose_ns[j]), Event.POSE, j


def write_bag(
    sequence_path: Path | str,
    bag_path: Path | str,
    *,
    storage: BagStorage | str = BagStorage.MCAP,
    depth: DepthUnit | str = DepthUnit.METRES,
    detections: bool = False,
    namespace: str = DEFAULT_NAMESPACE,
    compress: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    camera: CameraOverride | None = None,
) -> BagSummary:
    """Write the sequence at ``sequence_path`` as a rosbag2 folder at ``bag_path``.

    A real TUM folder exports too: its ground truth (100 Hz motion capture) goes in at its own
    timestamps, a folder without ``groundtruth.txt`` gets no pose topics, and ``detections``
    is refused (it has no ground-truth boxes). Its camera is its ``camera.yaml`` or ``camera``
    (as ``run`` takes one); with neither it is refused, not guessed as ``run`` guesses (with a
    warning): CameraInfo carries the guess into every node that plays the bag, with no
    warning there (the ROS default's fx 525 against a true 400 is 31 % off).
    ``compress`` zstd-compresses MCAP chunks, which every MCAP reader undoes; SQLite bags are
    written plain.
    """
    storage = parse_choice(BagStorage, storage, "storage")
    depth = parse_choice(DepthUnit, depth, "depth")
    form = DEPTH_FORMS[depth]
    names = TopicNames.under(namespace, form)
    if compress and storage is not BagStorage.MCAP:
        raise InputError("compression applies to MCAP bags (zstd chunks); drop it or use storage mcap")
    sequence_path, bag_path = Path(sequence_path), Path(bag_path)
    sequence = Sequence.open(sequence_path, camera=camera)
    _check_camera(sequence)
    _check_times(sequence)
    objects = None
    if detections:
        if not sequence.is_generated:
            raise InputError(
                f"{sequence_path}: detections need a generated sequence (gt/objects.jsonl); "
                "a real TUM folder exports without them"
            )
        objects = sequence.objects()
    notes = []
    if sequence.camera_source.depth_factor_source in FALLBACKS:
        notes.append(
            f"depth factor {sequence.intrinsics.depth_scale:g} per metre, TUM's (no camera.yaml): "
            "give --depth-factor F for a folder whose depth PNGs use another"
        )
    if sequence.groundtruth is None:
        notes.append(f"no groundtruth.txt: no {names.tf}, {names.pose} or {names.path}")
    store = typestore(detections)
    with StagedOutput(bag_path, OutputKind.ROSBAG, overwrite=overwrite, inputs=(sequence_path,)) as staged:
        inner = staged.path / _data_stem(staged.path, staged.target.name)  # rosbags names the file after it
        writer = Writer(inner, version=BAG_VERSION, storage_plugin=STORAGE_PLUGINS[storage])
        if compress:
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in _custom_data(sequence, form, names).items():
            writer.set_custom_data(key, value)
        with writer:
            counts = _BagWriter(writer, store, sequence, names, form, objects).write(progress)
        for item in inner.iterdir():
            os.rename(item, staged.path / item.name)
        inner.rmdir()
        size = sum(p.stat().st_size for p in staged.path.iterdir())
        staged.commit()
    topics = tuple(TopicCount(topic, msgtype, count) for (topic, msgtype), count in counts.items())
    return BagSummary(bag_path, storage, depth, len(sequence), topics, size, tuple(notes))


def _check_camera(sequence: Sequence) -> None:
    """Refuse a real folder whose calibration would be a guess from its name; where the name
    names a TUM sensor, the line spells out that sensor's published calibration as flags."""
    source = sequence.camera_source
    if not source.fallback:
        return
    hint = ""
    if source.source is CameraSource.TUM:
        k = sequence.intrinsics
        numbers = " ".join(f"{v:g}" for v in (k.fx, k.fy, k.cx, k.cy))
        distortion = " ".join(f"{v:g}" for v in k.distortion) if any(k.distortion) else ""
        hint = f" (for {source.detail}: --intrinsics {numbers}" + (
            f" --distortion {distortion})" if distortion else ")"
        )
    raise InputError(
        f"{sequence.root}: no camera.yaml and no camera given, and a bag's CameraInfo must hold "
        "the folder's own calibration, not a guess; give --camera FILE (an ORB-SLAM settings "
        f"file) or --intrinsics FX FY CX CY [--distortion K1 K2 P1 P2 [K3]] [--depth-factor F]{hint}"
    )


def _check_times(sequence: Sequence) -> None:
    """Refuse a timestamp a header stamp cannot hold (``TIME_MAX_S``), naming its file and line;
    ``run`` takes such a folder, so the reader does not refuse it."""
    for frame in sequence.frames:
        for kind, t in (("", frame.timestamp_s), ("depth ", frame.depth_timestamp_s)):
            if not 0 <= t < TIME_MAX_S:
                _refuse_time(frame.list_path, frame.list_line, f"{kind}timestamp {_seconds(t)}")
    gt = sequence.groundtruth
    if gt is not None:
        outside = np.flatnonzero(~((gt.timestamps_s >= 0) & (gt.timestamps_s < TIME_MAX_S)))
        if outside.size:
            row = int(outside[0])
            path = sequence.root / "groundtruth.txt"
            _refuse_time(path, gt.lines[row], f"timestamp {_seconds(float(gt.timestamps_s[row]))}")


def _seconds(t: float) -> str:
    """A timestamp as the files write it (6 decimals), or short where that runs to 300 digits."""
    return f"{t:.6f}" if abs(t) < 1e15 else f"{t:.6g}"


def _refuse_time(path: Path, line: int | None, what: str) -> None:
    where = path if line is None else f"{path}:{line}"
    raise InputError(
        f"{where}: {what} s is outside what a ROS 2 header stamp holds (int32 seconds: 0 to "
        f"2^31 s); shift the folder's times to export it"
    )


def _data_stem(staging: Path, name: str) -> str:
    """The bag folder's own name where ``name.mcap`` fits the file system, else ``DATA_STEM``;
    metadata.yaml lists the file, so players find it by either name."""
    try:
        limit = os.pathconf(staging, "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    longest = max(len(os.fsencode(f"{name}.{ext}")) for ext in ("mcap", "db3"))
    return name if longest <= limit else DATA_STEM


def typestore(detections: bool = False) -> Typestore:
    """Humble's message types, with vision_msgs' when detections are written."""
    store = get_typestore(TYPESTORE)
    if detections:
        types: dict[str, Any] = {}
        for name, text in VISION_MSGS.items():
            types.update(get_types_from_msg(text, name))
        store.register(types)
    return store


def _custom_data(sequence: Sequence, form: DepthForm, names: TopicNames) -> dict[str, str]:
    """What a user of the bag needs to read it right, in metadata.yaml's custom_data."""
    return {
        "depotbench.version": package_version(),
        "depotbench.sequence": sequence.root.resolve().name,
        "depotbench.depth": form.meaning,
        "depotbench.depth_scale": f"{sequence.intrinsics.depth_scale:g}",
        "depotbench.camera": f"{sequence.camera_source.source.value}: {sequence.camera_source.detail}",
        "depotbench.poses": (
            f"{names.tf} {WORLD_FRAME} -> {names.optical_frame} and {names.pose}: groundtruth.txt's "
            "camera-to-world pose of the optical frame (x right, y down, z forward)"
        ),
    }


class _BagWriter:
    """Builds and writes one sequence's messages in time order."""

    def __init__(
        self,
        writer: Writer,
        store: Typestore,
        sequence: Sequence,
        names: TopicNames,
        form: DepthForm,
        objects: list[tuple[ObjectState, ...]] | None,
    ) -> None:
        self.writer = writer
        self.store = store
        self.types = store.types
        self.sequence = sequence
        self.names = names
        self.form = form
        self.objects = objects
        self.counts: Counter[tuple[str, str]] = Counter()
        self.connections: dict[str, Any] = {}
        self._order: list[tuple[str, str]] = []  # the topics as connected: the summary's order
        self.handlers: dict[Event, Callable[[int, int], None]] = {
            Event.POSE: self._pose,
            Event.COLOR: self._color,
            Event.DEPTH: self._depth,
            Event.DETECTIONS: self._detections,
        }

    def write(self, progress: bool) -> Counter[tuple[str, str]]:
        """Messages in time order: the frames' few events sorted, merged as they come with the
        ground truth's rows (increasing, as the reader checks), never all held at once: 400,000
        rows of 100 Hz motion capture were 400,000 tuples before a message was written."""
        frame_events = sorted(self._frame_events())
        gt = self.sequence.groundtruth
        pose_ns = None if gt is None else stamps_ns(gt.timestamps_s)
        firsts = [e[0] for e in frame_events[:1]] + ([int(pose_ns[0])] if pose_ns is not None else [])
        if not firsts:
            return self.counts
        self._connect()
        start = min(firsts)
        self._static_tf(start)
        if pose_ns is not None:
            self._path(start, pose_ns)
        events = heapq.merge(frame_events, () if pose_ns is None else _pose_events(pose_ns))
        bar = progress_bar(
            total=len(self.sequence), desc="rosbag", unit="frame", disable=not progress, leave=False
        )
        with bar:
            for ns, kind, index in events:
                self.handlers[kind](ns, index)
                if kind is Event.COLOR:
                    bar.update(1)
        return Counter({key: self.counts[key] for key in self._order})

    def _frame_events(self) -> Iterator[tuple[int, Event, int]]:
        for i, frame in enumerate(self.sequence.frames):
            yield stamp_ns(frame.timestamp_s), Event.COLOR, i
            yield stamp_ns(frame.depth_timestamp_s), Event.DEPTH, i
            if self.objects is not None:
                yield stamp_ns(frame.timestamp_s), Event.DETECTIONS, i

    def _connect(self) -> None:
        n = self.names
        topics = [
            (n.color_image, "sensor_msgs/msg/Image", STREAM),
            (n.color_info, "sensor_msgs/msg/CameraInfo", STREAM),
            (n.depth_image, "sensor_msgs/msg/Image", STREAM),
            (n.depth_info, "sensor_msgs/msg/CameraInfo", STREAM),
            (n.tf_static, "tf2_msgs/msg/TFMessage", LATCHED),
        ]
        if self.sequence.groundtruth is not None:
            topics += [
                (n.tf, "tf2_msgs/msg/TFMessage", _qos(QosDurability.VOLATILE, 100)),  # tf2's broadcaster
                (n.pose, "geometry_msgs/msg/PoseStamped", STREAM),
                (n.path, "nav_msgs/msg/Path", LATCHED),
            ]
        if self.objects is not None:
            topics.append((n.detections, "vision_msgs/msg/Detection2DArray", STREAM))
        for topic, msgtype, qos in topics:
            self.connections[topic] = self.writer.add_connection(
                topic, msgtype, typestore=self.store, offered_qos_profiles=qos
            )
            self._order.append((topic, msgtype))

    def _put(self, topic: str, ns: int, message: Any) -> None:
        connection = self.connections[topic]
        self.writer.write(connection, ns, self.store.serialize_cdr(message, connection.msgtype))
        self.counts[(topic, connection.msgtype)] += 1

    # -- message parts ---------------------------------------------------------------

    def _header(self, ns: int, frame_id: str) -> Any:
        sec, nanosec = divmod(ns, 1_000_000_000)
        stamp = self.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def _pose_message(self, position: np.ndarray, quat_xyzw: np.ndarray) -> Any:
        t = self.types
        x, y, z = (float(v) for v in position)
        qx, qy, qz, qw = (float(v) for v in quat_xyzw)
        return t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )

    def _transform(
        self, ns: int, parent: str, child: str, position: np.ndarray, quat_xyzw: np.ndarray
    ) -> Any:
        t = self.types
        x, y, z = (float(v) for v in position)
        qx, qy, qz, qw = (float(v) for v in quat_xyzw)
        transform = t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
            rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )
        return t["geometry_msgs/msg/TransformStamped"](
            header=self._header(ns, parent), child_frame_id=child, transform=transform
        )

    def _image(self, ns: int, pixels: np.ndarray, encoding: str) -> Any:
        height, width = pixels.shape[:2]
        data = np.ascontiguousarray(pixels).view(np.uint8).reshape(-1)
        return self.types["sensor_msgs/msg/Image"](
            header=self._header(ns, self.names.optical_frame),
            height=height,
            width=width,
            encoding=encoding,
            is_bigendian=0,
            step=len(data) // height,
            data=data,
        )

    def _camera_info(self, ns: int) -> Any:
        """The pinhole and OpenCV's (k1, k2, p1, p2, k3) as plumb_bob; P = [K | 0], the raw
        image's own matrix, as a monocular camera's info carries when rectification keeps K."""
        k = self.sequence.intrinsics
        t = self.types
        return t["sensor_msgs/msg/CameraInfo"](
            header=self._header(ns, self.names.optical_frame),
            height=k.height,
            width=k.width,
            distortion_model="plumb_bob",
            d=np.array(k.distortion, dtype=np.float64),
            k=k.matrix.reshape(-1),
            r=np.eye(3).reshape(-1),
            p=np.hstack([k.matrix, np.zeros((3, 1))]).reshape(-1),
            binning_x=0,
            binning_y=0,
            roi=t["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            ),
        )

    # -- the messages ------------------------------------------------------------------

    def _static_tf(self, ns: int) -> None:
        """The optical frame's REP 103 body frame (x forward, y left, z up), for nodes told a
        robot-style base frame (RTAB-Map's frame_id, Nav2)."""
        quat = Rotation.from_matrix(OPTICAL_FROM_BODY).as_quat()
        zero = np.zeros(3)
        transform = self._transform(ns, self.names.optical_frame, self.names.body_frame, zero, quat)
        self._put(self.names.tf_static, ns, self.types["tf2_msgs/msg/TFMessage"](transforms=[transform]))

    def _path(self, ns: int, pose_ns: np.ndarray) -> None:
        """The whole true trajectory once, latched at the start: rviz draws it beside a SLAM
        estimate from the first frame on. A growing path would store n^2/2 poses (45 000 for
        300 frames), one at the end would show nothing until the end. Its bytes are built from
        the arrays (``path_cdr``): 400,000 PoseStamped objects took ~300 MB."""
        gt = self.sequence.groundtruth
        assert gt is not None
        data = path_cdr(ns, WORLD_FRAME, pose_ns, gt.positions_m, gt.quats_xyzw)
        connection = self.connections[self.names.path]
        self.writer.write(connection, ns, data)
        self.counts[(self.names.path, connection.msgtype)] += 1

    def _pose(self, ns: int, row: int) -> None:
        """groundtruth.txt's row as it stands: the file's position and quaternion, no round trip
        through a matrix."""
        gt = self.sequence.groundtruth
        assert gt is not None
        position, quat = gt.positions_m[row], gt.quats_xyzw[row]
        transform = self._transform(ns, WORLD_FRAME, self.names.optical_frame, position, quat)
        self._put(self.names.tf, ns, self.types["tf2_msgs/msg/TFMessage"](transforms=[transform]))
        pose = self.types["geometry_msgs/msg/PoseStamped"](
            header=self._header(ns, WORLD_FRAME), pose=self._pose_message(position, quat)
        )
        self._put(self.names.pose, ns, pose)

    def _color(self, ns: int, index: int) -> None:
        self._put(self.names.color_image, ns, self._image(ns, self.sequence.rgb(index), "rgb8"))
        self._put(self.names.color_info, ns, self._camera_info(ns))

    def _depth(self, ns: int, index: int) -> None:
        raw = self.sequence.depth_raw(index)
        where = self.sequence.frames[index].depth_path
        pixels = self.form.convert(raw, self.sequence.intrinsics.depth_scale, where)
        self._put(self.names.depth_image, ns, self._image(ns, pixels, self.form.encoding))
        self._put(self.names.depth_info, ns, self._camera_info(ns))

    def _detections(self, ns: int, index: int) -> None:
        """Each visible instance's box, class and id (the instance id, stable over frames) with
        score 1; its pose is the object's in the optical frame. Boxes are in pixel-edge
        coordinates, as detectors' wrappers publish them: column u covers [u, u+1)."""
        assert self.objects is not None
        t = self.types
        header = self._header(ns, self.names.optical_frame)
        camera_from_world = np.linalg.inv(self.sequence.world_from_camera(index))
        found = []
        for state in self.objects[index]:
            if state.box_xyxy is None:
                continue
            x0, y0, x1, y1 = state.box_xyxy
            camera_from_object = camera_from_world @ pose_matrix(
                np.array(state.position_m), np.array(state.quat_xyzw)
            )
            quat = Rotation.from_matrix(camera_from_object[:3, :3]).as_quat()
            hypothesis = t["vision_msgs/msg/ObjectHypothesisWithPose"](
                hypothesis=t["vision_msgs/msg/ObjectHypothesis"](class_id=state.class_name, score=1.0),
                pose=t["geometry_msgs/msg/PoseWithCovariance"](
                    pose=self._pose_message(camera_from_object[:3, 3], quat),
                    covariance=np.zeros(36),
                ),
            )
            center = t["vision_msgs/msg/Pose2D"](
                position=t["vision_msgs/msg/Point2D"](x=(x0 + x1) / 2, y=(y0 + y1) / 2), theta=0.0
            )
            box = t["vision_msgs/msg/BoundingBox2D"](
                center=center, size_x=float(x1 - x0), size_y=float(y1 - y0)
            )
            found.append(
                t["vision_msgs/msg/Detection2D"](
                    header=header, results=[hypothesis], bbox=box, id=str(state.instance_id)
                )
            )
        message = t["vision_msgs/msg/Detection2DArray"](header=header, detections=found)
        self._put(self.names.detections, ns, message)
