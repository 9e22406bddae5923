"""The one table between the bench's class names and COCO's, read by every part that meets both.

A COCO-trained detector says 'dining table' (Darknet's files: 'diningtable') where the bench
says 'desk', and 'tv' or 'tvmonitor' for its 'tv'; a training set for such a detector must
number the bench's boxes as COCO does (person 0, dining table 60, tv 62), or a fine-tuned
model's person is another id in every export. So:

- ``bench_name`` turns a model's (or a user's) class name into the bench's: the ONNX
  detector's class table, ``detect-eval``'s detections and ``export-dataset --names`` all
  go through it, so 'dining table', 'diningtable' and 'desk' are one class everywhere;
- ``coco_name`` is the other way, for the bench's classes COCO has (all but the pig);
- ``EXPORT_CLASSES`` is the export's class numbering: COCO's 80 by their index (as
  Ultralytics' coco.yaml numbers them, 0..79), then ``BENCH_ONLY`` from 80 on;
- ``EXPORT_CATEGORY_IDS`` is the same classes' numbering in COCO json, which is not the
  index: COCO's own category ids (1..90 with gaps), then ``BENCH_ONLY`` from 91 on.
"""

from __future__ import annotations

COCO_CLASSES: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog",
    "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella",
    "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball", "kite",
    "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket", "bottle",
    "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich", "orange",
    "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch", "potted plant",
    "bed", "dining table", "toilet", "tv", "laptop", "mouse", "remote", "keyboard", "cell phone",
    "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
    "teddy bear", "hair drier", "toothbrush",
)  # fmt: skip
"""COCO 2017's 80 detection classes in index order 0..79, spelled as Ultralytics' coco.yaml
spells them (tests hold this against that file and the shipped Darknet coco.names)."""

COCO_CATEGORY_IDS: tuple[int, ...] = (
    1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 27, 28,
    31, 32, 33, 34, 35, 36, 37, 38, 39, 40, 41, 42, 43, 44, 46, 47, 48, 49, 50, 51, 52, 53, 54, 55,
    56, 57, 58, 59, 60, 61, 62, 63, 64, 65, 67, 70, 72, 73, 74, 75, 76, 77, 78, 79, 80, 81, 82, 84,
    85, 86, 87, 88, 89, 90,
)  # fmt: skip
"""COCO's own ``category_id`` of each of ``COCO_CLASSES``, in the same order: the 2014 paper
numbered 91 categories and the detection set keeps 80 of them with their ids, so ids run 1..90
with 10 gaps (person 1, cat 17, dog 18, dining table 67, tv 72), not index + 1."""

DARKNET_SPELLINGS: dict[str, str] = {
    "tvmonitor": "tv",
    "motorbike": "motorcycle",
    "aeroplane": "airplane",
    "sofa": "couch",
    "pottedplant": "potted plant",
    "diningtable": "dining table",
}
"""Darknet's coco.names spellings (the shipped YOLOX-nano's file uses them) -> COCO's."""

COCO_OF_BENCH: dict[str, str] = {"desk": "dining table"}
"""The bench's classes COCO names otherwise: its desks are COCO's nearest class, a table.
Every other bench class COCO has keeps its name (person, dog, cat, bird, chair, tv, ...)."""

BENCH_ONLY: tuple[str, ...] = ("pig",)
"""The bench's classes without a COCO class, numbered 80, 81, ... in this order: append a
new one at the end, never reorder, so an id once exported keeps its meaning."""

EXPORT_CLASSES: tuple[str, ...] = COCO_CLASSES + BENCH_ONLY
"""The export's class names in id order (data.yaml's ``names``)."""

FIRST_BENCH_CATEGORY_ID = max(COCO_CATEGORY_IDS) + 1
"""COCO json ``category_id`` of the first class COCO lacks (pig 91): after COCO's highest, 90,
so no id of a COCO-trained model's table means a bench class."""

EXPORT_CATEGORY_IDS: tuple[int, ...] = COCO_CATEGORY_IDS + tuple(
    range(FIRST_BENCH_CATEGORY_ID, FIRST_BENCH_CATEGORY_ID + len(BENCH_ONLY))
)
"""The COCO json ``category_id`` of each of ``EXPORT_CLASSES``, in the same order."""

_BENCH_OF_COCO = {coco: bench for bench, coco in COCO_OF_BENCH.items()}


def bench_name(class_name: str) -> str:
    """A detector's or user's class name in the bench's words: Darknet's spelling to COCO's,
    COCO's to the bench's ('diningtable' and 'dining table' are 'desk'); others unchanged."""
    coco = DARKNET_SPELLINGS.get(class_name, class_name)
    return _BENCH_OF_COCO.get(coco, coco)


def coco_name(bench_class: str) -> str | None:
    """The COCO class of a bench class ('desk' -> 'dining table'), None where COCO has none."""
    name = COCO_OF_BENCH.get(bench_class, bench_class)
    return name if name in _COCO_INDEX else None


def export_name(bench_class: str) -> str | None:
    """The bench class's name in ``EXPORT_CLASSES`` (its COCO name, or its own for a
    ``BENCH_ONLY`` class); None for a class outside both (a kind registered at run time)."""
    coco = coco_name(bench_class)
    if coco is not None:
        return coco
    return bench_class if bench_class in BENCH_ONLY else None


_COCO_INDEX = {name: i for i, name in enumerate(COCO_CLASSES)}
