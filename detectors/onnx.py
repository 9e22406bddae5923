"""A YOLO detector on ONNX Runtime: YOLOX, YOLOv5- and YOLOv8-style outputs.

The layout is recognised from the output's shape for the model's input size:
- YOLOX (anchor-free, raw grid outputs): 1 x N x (5+C), N = sum over strides 8,
  16, 32 of the cells; decoded as xy = (raw + cell) * stride, wh = exp(raw) * stride.
- YOLOv5: 1 x 3N x (5+C), three anchors a cell, boxes already in input pixels.
- YOLOv8: 1 x (4+C) x N, no objectness, boxes already in input pixels.
Input: YOLOX takes BGR 0-255 placed top-left; YOLOv5/v8 take RGB 0-1, centred;
both letterboxed with grey 114. Scores are objectness x class probability (v8:
class probability); each box keeps its best class; then class-wise NMS.

A model is a user's file and may be hostile: its size, declared input, output shape and
class table are checked when it loads (or, for a symbolic output, when it first runs),
each refusal one line naming the model; a NaN or infinite output is no box.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from depotbench.core.assets import asset
from depotbench.core.errors import FileError, InputError
from depotbench.core.files import KIB, read_text
from depotbench.detectors.base import DetectorFrame
from depotbench.detectors.coco import bench_name
from depotbench.detectors.config import MAX_NAMES_BYTES, OnnxSettings, check_model_file
from depotbench.detectors.detection import Detection
from depotbench.detectors.priors import DEFAULT_PRIORS, PriorTable

COCO_NAMES = asset("models", "yolox_nano", "coco.names")
STRIDES = (8, 16, 32)
PAD_VALUE = 114
DEFAULT_SIDE = 640
"""The input side assumed where the model leaves it symbolic (Ultralytics' default)."""
MAX_INPUT_SIDE = 4096
"""The largest declared input side, px. YOLO exports use 320 to 1280 (1280: the P6 models);
4096 keeps the letterboxed input tensor within 4096 x 4096 x 3 float32 = 192 MiB, where a
212-byte model declaring 65536 x 65536 asked for about 22 GB."""
LAYOUT_SHAPES = {
    "yolox": "1 x N x (5+C), N the grid cells",
    "yolov5": "1 x 3N x (5+C)",
    "yolov8": "1 x (4+C) x N",
}


class OnnxModelError(InputError):
    """A model this detector cannot use (the message names the file): the user's to fix, so
    one line wherever it is raised, at load or at detection time."""


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


def class_count(shape: tuple[int, ...], layout: str, size_hw: tuple[int, int]) -> int:
    """The classes C of an output of ``shape`` in ``layout``; refused where ``decode`` could not
    read it (no class column, or YOLOX rows that are not the grid's cells)."""
    fits = len(shape) == 3 and shape[0] == 1
    classes = 0
    if fits:
        _, a, b = shape
        classes = a - 4 if layout == "yolov8" else b - 5
        fits = classes >= 1 and (layout != "yolox" or a == grid_cells(size_hw))
    if not fits:
        raise OnnxModelError(
            f"output shape {shape} does not fit layout {layout} ({LAYOUT_SHAPES[layout]}, C >= 1; "
            f"{grid_cells(size_hw)} grid cells for a {size_hw[1]}x{size_hw[0]} input)"
        )
    return classes


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
    with np.errstate(invalid="ignore", over="ignore"):  # inf - inf: such a row is dropped (class_wise_nms)
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
    """Indices kept by OpenCV's batched (per-class) NMS, best score first.

    A row whose box or score is NaN or infinite is dropped like one under the threshold: it
    is no box, and one infinite coordinate in OpenCV's per-class offsets spoils every box."""
    finite = np.isfinite(boxes).all(axis=1) & np.isfinite(scores)
    keep = finite & (scores >= score_threshold)
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
        self.settings = settings or OnnxSettings()
        self.priors = priors
        self.model = model
        self.name = f"onnx:{model.stem}"
        check_model_file(model)
        self.session = _session(model, self.settings.threads)
        self.input_name, self.size_hw = _image_input(model, self.session)
        shape = tuple(self.session.get_outputs()[0].shape)
        known = all(isinstance(d, int) for d in shape)
        self.layout = self.settings.layout
        if self.layout == "auto":
            if not known:
                shape, known = self._run(np.zeros((1, 3, *self.size_hw), np.float32)).shape, True
            self.layout = self._about_model(recognise_layout, shape, self.size_hw)
        self.names, self.names_from = self._class_names(model)
        if known:  # else its class count is known only once it runs: detect checks the boxes kept
            self._check_class_table(self._about_model(class_count, shape, self.layout, self.size_hw))

    def _about_model(self, check, *args):
        """``check(*args)``, its refusal prefixed with the model file."""
        try:
            return check(*args)
        except OnnxModelError as exc:
            raise OnnxModelError(f"{self.model}: {exc}") from None

    def _check_class_table(self, classes: int) -> None:
        if classes > len(self.names):
            raise OnnxModelError(
                f"{self.model}: the output has {classes} classes, but {self.names_from} "
                f"lists {_names(len(self.names))}"
            )

    def _class_names(self, model: Path) -> tuple[list[str], str]:
        """The class table and where it came from (for messages)."""
        if self.settings.names:
            path = Path(self.settings.names)
            return _bench_names(_read_names(model, path)), f"names file {path}"
        meta = self.session.get_modelmeta().custom_metadata_map
        if "names" in meta:  # ultralytics writes "{0: 'person', 1: 'bicycle', ...}"
            return _bench_names(_metadata_names(model, meta["names"])), "its metadata 'names'"
        return _bench_names(_read_names(model, COCO_NAMES)), f"names file {COCO_NAMES}"

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
        self._about_model(class_count, output.shape, self.layout, self.size_hw)  # a symbolic output
        boxes, scores, classes = decode(output, self.layout, self.size_hw)
        kept = class_wise_nms(boxes, scores, classes, self.settings.confidence, self.settings.nms_iou)
        if kept.size and int(classes[kept].max()) >= len(self.names):
            raise OnnxModelError(
                f"{self.model}: a box of class {int(classes[kept].max())} was kept, but "
                f"{self.names_from} lists {_names(len(self.names))}"
            )
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


def _session(model: Path, threads: int):
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    try:
        return ort.InferenceSession(str(model), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own types for unreadable models
        raise OnnxModelError(f"{model}: not a usable ONNX model: {str(exc).splitlines()[0]}") from None


def _image_input(model: Path, session) -> tuple[str, tuple[int, int]]:
    """The input's name and (H, W): one float image 1 x 3 x H x W, each side a multiple of 32
    from 32 to ``MAX_INPUT_SIDE`` (checked before anything of that size is allocated)."""
    inputs = session.get_inputs()
    dims = inputs[0].shape if len(inputs) == 1 else []
    image = len(dims) == 4 and _takes(dims[0], 1) and _takes(dims[1], 3)
    if not image or inputs[0].type != "tensor(float)":
        raise OnnxModelError(f"{model}: expected one float image input of shape 1 x 3 x H x W")
    h, w = (d if isinstance(d, int) else DEFAULT_SIDE for d in dims[2:])
    if not (32 <= h <= MAX_INPUT_SIDE and 32 <= w <= MAX_INPUT_SIDE):
        raise OnnxModelError(
            f"{model}: declared input {w}x{h} is out of range: each side must be 32 to {MAX_INPUT_SIDE} px"
        )
    if h % 32 or w % 32:
        raise OnnxModelError(f"{model}: input {w}x{h} is not a multiple of 32")
    return inputs[0].name, (h, w)


def _takes(dim: int | str | None, size: int) -> bool:
    """Whether a declared dimension takes ``size`` (a symbolic one, a name or None, takes any)."""
    return not isinstance(dim, int) or dim == size


def _names(count: int) -> str:
    return f"{count} name" if count == 1 else f"{count} names"


def _bench_names(names: list[str]) -> list[str]:
    return [bench_name(n) for n in names]


def _metadata_names(model: Path, text: str) -> list[str]:
    """Ultralytics' table, "{0: 'person', 1: 'bicycle', ...}" (or a list), in class order."""
    if len(text) > MAX_NAMES_BYTES:
        raise OnnxModelError(
            f"{model}: metadata 'names' is {len(text)} characters, more than the "
            f"{MAX_NAMES_BYTES // KIB} KiB limit for a class table"
        )
    try:
        table = ast.literal_eval(text)
        if not isinstance(table, dict | list | tuple):
            raise TypeError(type(table))
        keys = sorted(table) if isinstance(table, dict) else list(range(len(table)))
        names = [str(table[k]) for k in keys]
    # The parser reports nesting too deep for its stack (thousands of "-" in 64 KiB) as
    # MemoryError or RecursionError: a malformed table, not a machine out of memory.
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        raise OnnxModelError(f"{model}: metadata 'names' is not a class list") from None
    if keys != list(range(len(keys))):  # a gap would give every later class its neighbour's name
        raise OnnxModelError(f"{model}: metadata 'names' keys are not the classes 0 to {len(keys) - 1}")
    return names


def _read_names(model: Path, path: Path) -> list[str]:
    """One class name a line, from a regular file within ``MAX_NAMES_BYTES``."""
    try:
        text = read_text(path, MAX_NAMES_BYTES, "class names file")
    except FileNotFoundError:
        raise OnnxModelError(f"{model}: class names file {path} does not exist") from None
    except OSError as exc:
        raise OnnxModelError(f"{model}: class names file {path}: cannot be read ({exc.strerror})") from None
    except FileError as exc:
        raise OnnxModelError(f"{model}: class names file {exc}") from None
    names = [line.strip() for line in text.splitlines() if line.strip()]
    if not names:
        raise OnnxModelError(f"{model}: class names file {path} holds no names")
    return names
