"""``export-dataset``'s COCO json numbers categories with COCO's own ids (1..90 with gaps), not
the YOLO index + 1: a COCO-trained model's dog (18) must be the export's dog, not its cat.

Reference: COCO 2017's published category list (instances_val2017.json's ``categories``),
written out here by hand as name -> id, and pycocotools' own reader of the export."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main

from tests import test_coco_names
from tests.test_coco_names import scene

COCO_2017_CATEGORY_IDS = {
    "person": 1, "bicycle": 2, "car": 3, "motorcycle": 4, "airplane": 5, "bus": 6, "train": 7,
    "truck": 8, "boat": 9, "traffic light": 10, "fire hydrant": 11, "stop sign": 13,
    "parking meter": 14, "bench": 15, "bird": 16, "cat": 17, "dog": 18, "horse": 19, "sheep": 20,
    "cow": 21, "elephant": 22, "bear": 23, "zebra": 24, "giraffe": 25, "backpack": 27,
    "umbrella": 28, "handbag": 31, "tie": 32, "suitcase": 33, "frisbee": 34, "skis": 35,
    "snowboard": 36, "sports ball": 37, "kite": 38, "baseball bat": 39, "baseball glove": 40,
    "skateboard": 41, "surfboard": 42, "tennis racket": 43, "bottle": 44, "wine glass": 46,
    "cup": 47, "fork": 48, "knife": 49, "spoon": 50, "bowl": 51, "banana": 52, "apple": 53,
    "sandwich": 54, "orange": 55, "broccoli": 56, "carrot": 57, "hot dog": 58, "pizza": 59,
    "donut": 60, "cake": 61, "chair": 62, "couch": 63, "potted plant": 64, "bed": 65,
    "dining table": 67, "toilet": 70, "tv": 72, "laptop": 73, "mouse": 74, "remote": 75,
    "keyboard": 76, "cell phone": 77, "microwave": 78, "oven": 79, "toaster": 80, "sink": 81,
    "refrigerator": 82, "book": 84, "clock": 85, "vase": 86, "scissors": 87, "teddy bear": 88,
    "hair drier": 89, "toothbrush": 90,
}  # fmt: skip
"""COCO 2017's 80 detection categories as its annotation files number them."""

BOXES = {"dog": (2, 2, 20, 30), "cat": (24, 2, 62, 30), "bird": (2, 34, 30, 62)}
"""Three classes that index + 1 gave each other's ids (dog 17 = COCO's cat, cat 16 = bird)."""


@pytest.fixture
def export(tmp_path: Path, monkeypatch, capsys) -> Path:
    """One export of the person, desk, tv and pig scene and one of dog, cat and bird, both
    in the train part (the other sequence goes to val)."""
    for name, box in BOXES.items():
        monkeypatch.setitem(test_coco_names.BOXES, name, box)
    people = scene(tmp_path / "people", ("person", "desk", "tv", "pig"))
    animals = scene(tmp_path / "animals", tuple(BOXES))
    out = tmp_path / "ds"
    code = main(["export-dataset", str(people), str(animals), "-o", str(out), "--val", "animals"])
    assert code == 0, capsys.readouterr().err
    return out


def annotated(coco: dict) -> dict[str, set[int]]:
    """Category name -> the ids its annotations carry, read through the file's own table."""
    name_of = {c["id"]: c["name"] for c in coco["categories"]}
    found: dict[str, set[int]] = {}
    for a in coco["annotations"]:
        found.setdefault(name_of[a["category_id"]], set()).add(a["category_id"])
    return found


def test_coco_json_numbers_every_class_as_coco_2017_does(export: Path):
    parts = {"train": {"person", "dining table", "tv", "pig"}, "val": {"dog", "cat", "bird"}}
    for part, expected in parts.items():
        coco = json.loads((export / "annotations" / f"instances_{part}.json").read_text())
        categories = {c["name"]: c["id"] for c in coco["categories"]}
        ids = [c["id"] for c in coco["categories"]]
        assert len(ids) == len(set(ids)) == 81
        assert {n: categories[n] for n in COCO_2017_CATEGORY_IDS} == COCO_2017_CATEGORY_IDS
        assert categories["pig"] > max(COCO_2017_CATEGORY_IDS.values())  # COCO lacks it: after 90
        assert set(annotated(coco)) == expected
        for name in expected - {"pig"}:
            assert annotated(coco)[name] == {COCO_2017_CATEGORY_IDS[name]}, name


def test_yolo_labels_keep_the_index_numbering(export: Path):
    names = (export / "data.yaml").read_text()
    files = (export / "labels" / "val").glob("*.txt")
    labels = {line.split()[0] for p in files for line in p.read_text().splitlines()}
    assert labels == {"14", "15", "16"}  # bird, cat, dog in COCO's index order
    assert "\n  14: bird\n  15: cat\n  16: dog\n" in names


def test_pycocotools_reads_the_export_with_coco_s_ids(export: Path):
    coco_api = pytest.importorskip("pycocotools.coco")
    coco = coco_api.COCO(str(export / "annotations" / "instances_val.json"))
    for name in BOXES:
        (category,) = coco.getCatIds(catNms=[name])
        assert category == COCO_2017_CATEGORY_IDS[name]
        boxes = [a["bbox"] for a in coco.loadAnns(coco.getAnnIds(catIds=[category]))]
        x0, y0, x1, y1 = BOXES[name]
        assert boxes == [[x0, y0, x1 - x0, y1 - y0]] * 2  # two frames, one box each
