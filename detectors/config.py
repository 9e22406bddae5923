"""A detector as typed data: which one, its settings, its faults and its class priors.

The CLI's ``--detector groundtruth|onnx|onnx:PATH|none`` with ``--detector-set``,
``--fault`` and ``--class-prior`` become one ``DetectorConfig`` at the edge;
everything after that (harness, cache, metrics) works on this value. Its
``key`` names the detections it produces, so cached detections are reused only
by an identical detector (the model file is hashed, not its path).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field, fields, replace
from enum import StrEnum
from pathlib import Path
from typing import Any

from depotbench.core.assets import asset
from depotbench.core.errors import FileError, InputError
from depotbench.core.files import MIB, file_digest, open_regular
from depotbench.detectors.detection import Prior
from depotbench.detectors.faults import Faults, check_range
from depotbench.detectors.priors import DEFAULT_PRIORS, PriorTable

SHIPPED_MODEL = asset("models", "yolox_nano", "yolox_nano.onnx")
MAX_NAMES_BYTES = 64 * 1024
"""A class table (names file or metadata): COCO's 80 names take 624 bytes, LVIS's 1203 about 20 KiB."""
MAX_MODEL_BYTES = 1024 * MIB
"""An ONNX model file: the shipped YOLOX-nano is 3.6 MB and YOLOv8x about 260 MB. A larger
file is refused before it is hashed: a 5 GB sparse "model" took 37 s to hash in full before
ONNX Runtime refused it."""


class DetectorKind(StrEnum):
    NONE = "none"
    GROUNDTRUTH = "groundtruth"
    ONNX = "onnx"


class DetectorConfigError(ValueError):
    """A detector name or setting that cannot be used."""


@dataclass(frozen=True)
class OnnxSettings:
    confidence: float = 0.3
    """Score threshold (objectness x class probability)."""
    nms_iou: float = 0.45
    """Class-wise non-maximum suppression: boxes of one class overlapping more than this merge."""
    threads: int = 1
    """ONNX Runtime intra-op threads (CPU)."""
    layout: str = "auto"
    """auto, yolox, yolov5 or yolov8 (auto: recognised from the output's shape)."""
    names: str = ""
    """A file of class names, one a line; default: the model's metadata, or COCO's for 80 classes."""

    def __post_init__(self) -> None:
        _in_range("confidence", self.confidence, 0.0, 1.0)
        _in_range("nms_iou", self.nms_iou, 0.0, 1.0)
        _in_range("threads", self.threads, 1, 256)
        if self.layout not in ("auto", "yolox", "yolov5", "yolov8"):
            raise DetectorConfigError(f"layout {self.layout!r}: choose auto, yolox, yolov5 or yolov8")


@dataclass(frozen=True)
class DetectorConfig:
    kind: DetectorKind = DetectorKind.GROUNDTRUTH
    model: Path | None = None
    """``onnx``: the model file; the shipped YOLOX-nano when None."""
    onnx: OnnxSettings = field(default_factory=OnnxSettings)
    min_visible_pixels: int = 20
    """``groundtruth``: objects with fewer visible pixels get no box."""
    faults: Faults = field(default_factory=Faults)
    priors: PriorTable = DEFAULT_PRIORS

    def __post_init__(self) -> None:
        _in_range("min_visible_pixels", self.min_visible_pixels, 0, 10**8)
        if self.kind is DetectorKind.NONE and (self.faults.active or self.model is not None):
            raise DetectorConfigError("--detector none takes no faults and no model")
        if self.kind is not DetectorKind.ONNX and self.model is not None:
            raise DetectorConfigError(f"--detector {self.kind.value} takes no model file")

    @property
    def model_path(self) -> Path:
        return self.model or SHIPPED_MODEL

    @property
    def label(self) -> str:
        """For tables and gates: 'groundtruth', 'onnx:yolox_nano', with the fault settings that
        differ from none, 'groundtruth+latency=3,miss=0.5' (one label per fault model)."""
        name = self.kind.value
        if self.kind is DetectorKind.ONNX:
            name += f":{self.model_path.stem}"
        return name + (f"+{self.faults.summary()}" if self.faults.active else "")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind.value}
        if self.kind is DetectorKind.ONNX:
            out["model"] = str(self.model_path)
            out["model_sha256"] = file_sha256(self.model_path)
            out["onnx"] = {f.name: getattr(self.onnx, f.name) for f in fields(self.onnx)}
            if self.onnx.names:  # the class table's bytes name the boxes as much as the model's do
                out["names_sha256"] = _names_sha256(Path(self.onnx.names))
        if self.kind is DetectorKind.GROUNDTRUTH:
            out["min_visible_pixels"] = self.min_visible_pixels
        if self.kind is not DetectorKind.NONE:
            out["faults"] = self.faults.to_dict() if self.faults.active else None
            out["priors"] = {name: prior.value for name, prior in self.priors.overrides}
        return out

    def base(self) -> DetectorConfig:
        """The same detector without faults: what the cache stores (faults are cheap to redo)."""
        return replace(self, faults=Faults())

    def key(self) -> str:
        """A content hash of everything that shapes the detections."""
        text = json.dumps(self.to_dict() | {"model": None}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def with_settings(self, settings: dict[str, str]) -> DetectorConfig:
        """``--detector-set`` overrides: ONNX settings, or min_visible_pixels."""
        onnx: dict[str, Any] = {}
        top: dict[str, Any] = {}
        kinds = {f.name: f.type for f in fields(OnnxSettings)}
        for name, text in settings.items():
            if name == "min_visible_pixels":
                top[name] = _number(name, text, int)
            elif name in kinds:
                if self.kind is not DetectorKind.ONNX:
                    raise DetectorConfigError(f"--detector-set {name}: only --detector onnx takes it")
                kind = kinds[name]
                onnx[name] = text if kind in ("str", str) else _number(name, text, kind)
            else:
                known = ", ".join(sorted({"min_visible_pixels", *kinds}))
                raise DetectorConfigError(f"unknown detector setting {name!r}; known: {known}")
        return replace(self, onnx=replace(self.onnx, **onnx), **top)


def parse_detector(
    text: str,
    settings: dict[str, str] | None = None,
    faults: dict[str, str] | None = None,
    priors: dict[str, str] | None = None,
) -> DetectorConfig:
    """The CLI's words as a ``DetectorConfig``: 'none', 'groundtruth', 'onnx' or 'onnx:PATH'."""
    kind_text, _, path = text.partition(":")
    try:
        kind = DetectorKind(kind_text)
    except ValueError:
        choices = "none, groundtruth, onnx, onnx:PATH"
        raise DetectorConfigError(f"unknown detector {text!r}; choose one of {choices}") from None
    if path and kind is not DetectorKind.ONNX:
        raise DetectorConfigError(f"--detector {text}: only onnx takes a model path")
    if kind is DetectorKind.ONNX and ":" in text and not path:
        raise DetectorConfigError("--detector onnx: empty model path")
    try:
        config = DetectorConfig(kind, Path(path) if path else None)
        config = config.with_settings(settings or {})
        if faults:
            if kind is DetectorKind.NONE:
                raise DetectorConfigError("--fault needs a detector (not --detector none)")
            config = replace(config, faults=config.faults.with_settings(faults))
        if priors:
            config = replace(config, priors=config.priors.with_overrides(priors))
    except ValueError as exc:
        raise DetectorConfigError(str(exc)) from None
    return config


def _names_sha256(path: Path) -> str | None:
    """The names file's content hash; None when it cannot be read (the detector, built
    next, then refuses it by name)."""
    try:
        return file_digest(path, "class names file", MAX_NAMES_BYTES).hex()
    except (OSError, FileError):
        return None


def check_model_file(path: Path) -> None:
    """Refuse, in one line naming it, a model path that is missing, not a regular file (a FIFO
    blocks its reader, /dev/zero never ends) or larger than ``MAX_MODEL_BYTES``."""
    os.close(_open_model(path))


def file_sha256(path: Path) -> str:
    """The model file's content hash, read only from a regular file within ``MAX_MODEL_BYTES``."""
    digest = hashlib.sha256()
    size = 0
    with os.fdopen(_open_model(path), "rb") as handle:
        try:
            for block in iter(lambda: handle.read(1 << 20), b""):
                size += len(block)
                if size > MAX_MODEL_BYTES:
                    limit = f"{MAX_MODEL_BYTES // MIB} MiB"
                    raise FileError(
                        path, None, f"grew beyond the {limit} limit for a model file while hashed"
                    )
                digest.update(block)
        except OSError as exc:
            raise FileError(path, None, f"cannot be read ({exc.strerror or exc})") from None
    return digest.hexdigest()


def _open_model(path: Path) -> int:
    try:
        return open_regular(path, MAX_MODEL_BYTES, "model file")
    except FileNotFoundError:
        raise InputError(f"--detector onnx: model file {path} does not exist") from None
    except OSError as exc:  # a folder on the way that is a file, no permission, a loop of links
        raise FileError(path, None, f"cannot be opened ({exc.strerror or exc})") from None


def _number(name: str, text: str, kind: Any) -> int | float:
    try:
        return int(text) if kind in ("int", int) else float(text)
    except ValueError:
        raise DetectorConfigError(f"detector setting {name}={text!r} is not a number") from None


def _in_range(name: str, value: float, low: float, high: float) -> None:
    check_range(f"detector setting {name}", value, low, high, DetectorConfigError)


__all__ = [
    "DetectorConfig",
    "DetectorConfigError",
    "DetectorKind",
    "OnnxSettings",
    "Prior",
    "check_model_file",
    "parse_detector",
]
