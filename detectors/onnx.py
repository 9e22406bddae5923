"""A YOLO detector on ONNX Runtime: YOLOX, YOLOv5- and YOLOv8-style outputs.

The layout is recognised from the output's shape for the model's input size:
- YOLOX (anchor-free, raw grid outputs): 1 x N x (5+C), N = sum over strides 8,
  16, 32 of the cells; decoded as xy = (raw + cell) * stride, wh = exp(raw) * stride.
- YOLOv5: 1 x 3N x (5+C), three anchors a cell, boxes already in input pixels.
- YOLOv8: 1 x (4+C) x N, no objectness, boxes already in input pixels.
Input: YOLOX takes BGR 0-255 placed top-left; YOLOv5/v8 take RGB 0-1, centred;
both letterboxed with grey 114. Scores are objectness x class probability (v8:
class probability); each box keeps its best class; then class-wise NMS.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from detectors.base import DetectorFrame
from detectors.config import OnnxSettings
from detectors.detection import Detection
from detectors.priors import DEFAULT_PRIORS, PriorTable, bench_name

COCO_NAMES = Path(__file__).resolve().parent.parent / "assets" / "models" / "yolox_nano" / "coco.names"
STRIDES = (8, 16, 32)
PAD_VALUE = 114


class OnnxModelError(ValueError):
    """A model this detector cannot use (the message names the file)."""


@dataclass(frozen=True)
class Letterbox:
    """How an image was fitted into the network input."""

    scale: float
    pad_x: float
    pad_y: float


def letterbox(image: np.ndarray, size_hw: tuple[int, int], centre: bool) -> tuple[np.ndarray, Letterbox]:
    """Resize keeping the aspect ratio, pad with grey 114 (top-left or centred)."""
    height, width = image.shape[:2]
    scale = min(size_hw[0] / height, size_hw[1] / width)
    new_w, new_h = int(round(width * scale)), int(round(height * scale))
    resized = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    out = np.full((size_hw[0], size_hw[1], image.shape[2]), PAD_VALUE, dtype=np.uint8)
    pad_x = (size_hw[1] - new_w) // 2 if centre else 0
    pad_y = (size_hw[0] - new_h) // 2 if centre else 0
    out[pad_y : pad_y + new_h, pad_x : pad_x + new_w] = resized
    return out, Letterbox(scale, float(pad_x), float(pad_y))


def grid_cells(size_hw: tuple[int, int]) -> int:
    return sum((size_hw[0] // s) * (size_hw[1] // s) for s in STRIDES)


def recognise_layout(shape: tuple[int, ...], size_hw: tuple[int, int]) -> str:
    """yolox, yolov5 or yolov8 from an output shape (see the module docstring)."""
    if len(shape) != 3 or shape[0] != 1:
        raise OnnxModelError(f"output shape {shape}: expected 1 x N x (5+C) or 1 x (4+C) x N")
    cells = grid_cells(size_hw)
    _, a, b = shape
    if b == cells and a >= 5:
        return "yolov8"
    if a == cells and b >= 6:
        return "yolox"
    if a == 3 * cells and b >= 6:
        return "yolov5"
    raise OnnxModelError(
        f"output shape {shape} matches no YOLO layout for a {size_hw[1]}x{size_hw[0]} input "
        f"({cells} grid cells at strides {STRIDES}); set layout= explicitly"
    )


def decode(
    output: np.ndarray, layout: str, size_hw: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boxes (xyxy in input pixels), scores and class ids of every row."""
    if layout == "yolov8":
        rows = output[0].T
        xywh, probs = rows[:, :4], rows[:, 4:]
        classes = probs.argmax(axis=1)
        scores = probs[np.arange(len(rows)), classes]
    else:
        rows = output[0]
        xywh = rows[:, :4].copy()
        if layout == "yolox":
            grid, stride = _yolox_grid(size_hw)
            xywh[:, :2] = (xywh[:, :2] + grid) * stride[:, None]
            xywh[:, 2:] = np.exp(np.minimum(xywh[:, 2:], 20.0)) * stride[:, None]
        probs = rows[:, 5:]
        classes = probs.argmax(axis=1)
        scores = rows[:, 4] * probs[np.arange(len(rows)), classes]
    boxes = np.concatenate([xywh[:, :2] - xywh[:, 2:] / 2, xywh[:, :2] + xywh[:, 2:] / 2], axis=1)
    return boxes.astype(np.float64), scores.astype(np.float64), classes


def _yolox_grid(size_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    grids, strides = [], []
    for s in STRIDES:
        h, w = size_hw[0] // s, size_hw[1] // s
        ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        grids.append(np.stack([xs.ravel(), ys.ravel()], axis=1))
        strides.append(np.full(h * w, s))
    return np.concatenate(grids).astype(np.float32), np.concatenate(strides).astype(np.float32)


def class_wise_nms(
    boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray, score_threshold: float, iou: float
) -> np.ndarray:
    """Indices kept by OpenCV's batched (per-class) NMS, best score first."""
    keep = scores >= score_threshold
    if not keep.any():
        return np.zeros(0, int)
    index = np.flatnonzero(keep)
    xywh = np.concatenate([boxes[index, :2], boxes[index, 2:] - boxes[index, :2]], axis=1)
    kept = cv2.dnn.NMSBoxesBatched(
        xywh.tolist(), scores[index].tolist(), classes[index].astype(int).tolist(), score_threshold, iou
    )
    kept = index[np.asarray(kept, int).ravel()]
    return kept[np.argsort(-scores[kept], kind="stable")]


class OnnxDetector:
    def __init__(
        self, model: Path, settings: OnnxSettings | None = None, priors: PriorTable = DEFAULT_PRIORS
    ) -> None:
        import onnxruntime as ort

        self.settings = settings or OnnxSettings()
        self.priors = priors
        self.name = f"onnx:{model.stem}"
        options = ort.SessionOptions()
        options.intra_op_num_threads = self.settings.threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(model), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own types for unreadable models
            raise OnnxModelError(f"{model}: not a usable ONNX model: {str(exc).splitlines()[0]}") from None
        inputs = self.session.get_inputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise OnnxModelError(f"{model}: expected one image input of shape 1 x 3 x H x W")
        self.input_name = inputs[0].name
        h, w = inputs[0].shape[2:]
        self.size_hw = (h if isinstance(h, int) else 640, w if isinstance(w, int) else 640)
        if self.size_hw[0] % 32 or self.size_hw[1] % 32:
            raise OnnxModelError(
                f"{model}: input {self.size_hw[1]}x{self.size_hw[0]} is not a multiple of 32"
            )
        self.layout = self.settings.layout
        if self.layout == "auto":
            shape = self.session.get_outputs()[0].shape
            if not all(isinstance(d, int) for d in shape):
                shape = self._run(np.zeros((1, 3, *self.size_hw), np.float32)).shape
            self.layout = recognise_layout(tuple(shape), self.size_hw)
        self.names = [bench_name(n) for n in self._class_names(model)]

    def _class_names(self, model: Path) -> list[str]:
        if self.settings.names:
            return _read_names(Path(self.settings.names))
        meta = self.session.get_modelmeta().custom_metadata_map
        if "names" in meta:  # ultralytics writes "{0: 'person', 1: 'bicycle', ...}"
            try:
                table = ast.literal_eval(meta["names"])
                if isinstance(table, dict):
                    return [str(table[i]) for i in sorted(table)]
                return [str(n) for n in table]
            except (ValueError, SyntaxError, KeyError, TypeError):
                raise OnnxModelError(f"{model}: metadata 'names' is not a class list") from None
        return _read_names(COCO_NAMES)

    def _run(self, tensor: np.ndarray) -> np.ndarray:
        return np.asarray(self.session.run(None, {self.input_name: tensor})[0])

    def preprocess(self, rgb: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        yolox = self.layout == "yolox"
        image = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if yolox else rgb
        boxed, fit = letterbox(image, self.size_hw, centre=not yolox)
        tensor = boxed.transpose(2, 0, 1)[None].astype(np.float32)
        return (tensor if yolox else tensor / np.float32(255.0)), fit

    def detect(self, frame: DetectorFrame) -> tuple[Detection, ...]:
        tensor, fit = self.preprocess(frame.rgb)
        output = self._run(tensor)
        boxes, scores, classes = decode(output, self.layout, self.size_hw)
        if classes.size and int(classes.max()) >= len(self.names):
            raise OnnxModelError(
                f"{self.name}: class {int(classes.max())} has no name ({len(self.names)} given)"
            )
        kept = class_wise_nms(boxes, scores, classes, self.settings.confidence, self.settings.nms_iou)
        height, width = frame.rgb.shape[:2]
        out = []
        for i in kept:
            x0, y0, x1, y1 = boxes[i]
            x0, x1 = ((np.array([x0, x1]) - fit.pad_x) / fit.scale).clip(0, width)
            y0, y1 = ((np.array([y0, y1]) - fit.pad_y) / fit.scale).clip(0, height)
            if x1 - x0 < 1 or y1 - y0 < 1:
                continue
            name = self.names[int(classes[i])]
            score = float(min(1.0, max(0.0, scores[i])))
            out.append(
                Detection((float(x0), float(y0), float(x1), float(y1)), name, self.priors.prior(name), score)
            )
        return tuple(out)


def _read_names(path: Path) -> list[str]:
    try:
        names = [line.strip() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    except OSError as exc:
        raise OnnxModelError(f"{path}: cannot read class names: {exc.strerror}") from None
    if not names:
        raise OnnxModelError(f"{path}: no class names")
    return names
