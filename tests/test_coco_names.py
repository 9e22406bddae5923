"""The bench's class names against COCO's (``depotbench.detectors.coco``), and the exports that
other tools read as they are: data.yaml from any working directory, COCO's class ids in every
export, ``detect-eval --json`` on stdout and its ``-o`` file.

References: Ultralytics' coco.yaml and its dataset check (where ultralytics is installed), the
shipped Darknet coco.names, and Ultralytics' documented data.yaml rules read independently."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from depotbench.core.camera import Intrinsics
from depotbench.detectors.coco import BENCH_ONLY, COCO_CLASSES, DARKNET_SPELLINGS, bench_name, export_name
from depotbench.detectors.priors import DEFAULT_PRIORS
from depotbench.eval.cli.main import main
from depotbench.sim.ground_truth import ObjectState
from depotbench.sim.sequence import SequenceWriter

from tests.test_output import one_error_line

SIZE = Intrinsics(fx=50.0, fy=50.0, cx=31.5, cy=31.5, width=64, height=64)
BOXES = {  # well apart: no box overlaps another
    "person": (2, 2, 20, 30),
    "desk": (24, 2, 62, 30),
    "tv": (2, 34, 30, 62),
    "pig": (34, 34, 62, 62),
}


def scene(root: Path, classes: tuple[str, ...], frames: int = 2, seed: int = 0) -> Path:
    """A generated sequence of ``frames`` frames whose objects are ``classes``, each whole in view
    at its box of ``BOXES`` (visible pixels = box area)."""
    rng = np.random.default_rng(seed)
    with SequenceWriter(root, SIZE, fps=30.0, meta={"scenario": {"name": root.name}, "seed": seed}) as w:
        for k in range(frames):
            objects = []
            for i, name in enumerate(classes, start=1):
                x0, y0, x1, y1 = BOXES[name]
                area = (x1 - x0) * (y1 - y0)
                objects.append(
                    ObjectState(
                        i, name, DEFAULT_PRIORS.prior(name).value, (float(i), 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                        (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False, BOXES[name], area, area, False,
                    )
                )  # fmt: skip
            rgb = rng.integers(0, 256, (SIZE.height, SIZE.width, 3), dtype=np.uint8)
            depth = np.full((SIZE.height, SIZE.width), 2.0, np.float32)
            instances = np.zeros((SIZE.height, SIZE.width), np.uint16)
            w.add_frame(1.0 + k / 30.0, rgb, depth, np.eye(4), instances, tuple(objects), None)
    return root


# -- the table -------------------------------------------------------------------------------------


def test_coco_classes_are_the_shipped_darknet_table_in_coco_spelling():
    from depotbench.detectors.onnx import COCO_NAMES

    darknet = [line.strip() for line in COCO_NAMES.read_text().splitlines() if line.strip()]
    assert [DARKNET_SPELLINGS.get(n, n) for n in darknet] == list(COCO_CLASSES)


def test_coco_classes_are_ultralytics_coco_yaml():
    """Read as a file, so the 5 MB package suffices (``pip install --no-deps ultralytics``)."""
    spec = importlib.util.find_spec("ultralytics")
    if spec is None or spec.origin is None:
        pytest.skip("ultralytics is not installed: its coco.yaml is the reference here")
    coco_yaml = Path(spec.origin).parent / "cfg" / "datasets" / "coco.yaml"
    names = yaml.safe_load(coco_yaml.read_text())["names"]
    assert [names[i] for i in range(len(names))] == list(COCO_CLASSES)


def _bench_classes() -> set[str]:
    """Every class a built-in scene can hold: the actor kinds', the layout's objects' (over a
    few seeds: the desk's props are drawn) and the chairs' (``sim.world`` registers 'chair')."""
    from depotbench.sim import actor_registry
    from depotbench.sim.layout import plan_layout
    from depotbench.sim.spec import LayoutSpec

    found = {kind.class_name for kind in actor_registry.BUILTIN} | {"chair"}
    for seed in range(5):
        found |= {o.class_name for o in plan_layout(LayoutSpec(), np.random.default_rng(seed)).objects}
    return found


def test_every_bench_class_has_a_fixed_export_id_and_reads_back_as_itself():
    classes = _bench_classes()
    assert {"person", "dog", "cat", "bird", "pig", "desk", "tv", "chair"} <= classes
    for name in classes:
        exported = export_name(name)
        assert exported is not None, f"{name}: add it to BENCH_ONLY (no COCO class)"
        assert bench_name(exported) == name  # the detector's word for it is the truth's
    assert export_name("desk") == "dining table" and export_name("pig") == "pig" and "pig" in BENCH_ONLY
    assert export_name("goat") is None


@pytest.mark.parametrize(
    ("model", "bench"),
    [("dining table", "desk"), ("diningtable", "desk"), ("tvmonitor", "tv"), ("tv", "tv"), ("sofa", "couch")],
)
def test_model_spellings_are_the_bench_classes_and_class_priors_take_them(model: str, bench: str):
    assert bench_name(model) == bench
    table = DEFAULT_PRIORS.with_overrides({model: "static"})
    assert table.prior(bench).value == "static"


# -- export-dataset ----------------------------------------------------------------------------------


def _labels(dataset: Path) -> dict[str, list[int]]:
    """Image stem -> the class ids of its label lines."""
    return {
        p.stem: [int(line.split()[0]) for line in p.read_text().splitlines()]
        for p in sorted((dataset / "labels").rglob("*.txt"))
    }


def test_two_exports_of_different_scenes_number_each_class_alike(tmp_path: Path, capsys):
    """Before, ids were the sorted classes present: person was 0 in one export and 1 in the other."""
    scene(tmp_path / "office", ("desk", "person", "tv"))
    scene(tmp_path / "pen", ("person", "pig"))
    for name in ("office", "pen"):
        assert main(["export-dataset", str(tmp_path / name), "-o", str(tmp_path / f"ds_{name}")]) == 0
    office, pen = _labels(tmp_path / "ds_office"), _labels(tmp_path / "ds_pen")
    assert set(map(tuple, office.values())) == {(60, 0, 62)}  # dining table, person, tv: COCO's ids
    assert set(map(tuple, pen.values())) == {(0, 80)}  # person, then the pig after COCO's 80
    names = [
        yaml.safe_load((tmp_path / f"ds_{n}" / "data.yaml").read_text())["names"] for n in ("office", "pen")
    ]
    assert names[0] == names[1] == dict(enumerate(COCO_CLASSES + BENCH_ONLY))
    assert "class ids: desk 60, person 0, tv 62" in capsys.readouterr().out


def test_a_names_file_numbers_by_its_lines_and_reads_coco_spellings(tmp_path: Path, capsys):
    scene(tmp_path / "office", ("desk", "person", "tv"))
    (tmp_path / "names.txt").write_text("tvmonitor\nperson\ndining table\n")
    args = ["export-dataset", str(tmp_path / "office"), "-o", str(tmp_path / "ds"), "--names"]
    assert main([*args, str(tmp_path / "names.txt")]) == 0
    assert set(map(tuple, _labels(tmp_path / "ds").values())) == {(2, 1, 0)}
    data = yaml.safe_load((tmp_path / "ds" / "data.yaml").read_text())
    assert data["names"] == {0: "tvmonitor", 1: "person", 2: "dining table"} and data["nc"] == 3
    capsys.readouterr()


def test_a_class_outside_both_tables_is_numbered_after_them_and_named(tmp_path: Path, capsys):
    root = scene(tmp_path / "farm", ("person", "pig"))
    objects = root / "gt" / "objects.jsonl"
    objects.write_text(objects.read_text().replace('"pig"', '"goat"'))
    assert main(["export-dataset", str(root), "-o", str(tmp_path / "ds")]) == 0
    assert yaml.safe_load((tmp_path / "ds" / "data.yaml").read_text())["names"][81] == "goat"
    assert set(map(tuple, _labels(tmp_path / "ds").values())) == {(0, 81)}
    assert "numbered after them in this export only: goat" in capsys.readouterr().out


def _documented_check(data_yaml: Path) -> int:
    """data.yaml read as Ultralytics documents it, without Ultralytics: ``path`` is the dataset
    root (a relative one is looked up against the working directory or the datasets folder, so
    it must be absolute here), ``train``/``val`` are relative to it, each image has a label file
    of the same name with ``.txt`` under ``labels`` where the image is under ``images``, one row
    ``class x y w h`` per object, class < len(names), coordinates normalised. Returns the boxes."""
    data = yaml.safe_load(data_yaml.read_text())
    root = Path(data["path"])
    assert root.is_absolute(), data["path"]
    names = data["names"]
    assert list(names) == list(range(len(names))) and data["nc"] == len(names)
    boxes = 0
    for part in ("train", "val"):
        images = sorted((root / data[part]).iterdir())
        assert images, f"no {part} images under {root / data[part]}"
        for image in images:
            parts = list(image.parts)
            at = len(parts) - 1 - parts[::-1].index("images")
            label = Path(*parts[:at], "labels", *parts[at + 1 :]).with_suffix(".txt")
            for row in label.read_text().splitlines():
                cls, *xywh = row.split()
                assert 0 <= int(cls) < len(names) and all(0.0 <= float(v) <= 1.0 for v in xywh)
                boxes += 1
    return boxes


def test_data_yaml_works_from_another_working_directory_and_after_a_move(tmp_path: Path, monkeypatch, capsys):
    """`path: .` resolved against the working directory: from anywhere else, no images."""
    scene(tmp_path / "office", ("desk", "person"), seed=1)
    scene(tmp_path / "pen", ("person", "pig"), seed=2)
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert main(["export-dataset", "../office", "../pen", "-o", "../ds", "--val", "pen"]) == 0
    assert _documented_check(tmp_path / "ds" / "data.yaml") == 2 * 2 + 2 * 2
    # Moved, the folder works again once `path` says where it is (data.yaml's comment says so).
    moved = Path(shutil.move(tmp_path / "ds", tmp_path / "moved"))
    with pytest.raises(FileNotFoundError):
        _documented_check(moved / "data.yaml")
    text = (moved / "data.yaml").read_text()
    assert "after moving the folder, set `path`" in text
    data = yaml.safe_load(text)
    (moved / "data.yaml").write_text(yaml.safe_dump({**data, "path": str(moved)}))
    assert _documented_check(moved / "data.yaml") == 8
    capsys.readouterr()


@pytest.mark.slow
def test_ultralytics_accepts_the_export_from_another_working_directory(tmp_path: Path, monkeypatch, capsys):
    """Ultralytics' own check. It imports torch (and reads torchvision's version) at import, so
    it runs where those are installed; the documented check above runs everywhere."""
    monkeypatch.setenv("YOLO_CONFIG_DIR", str(tmp_path / "ultralytics-settings"))
    monkeypatch.setenv("YOLO_OFFLINE", "1")
    utils = pytest.importorskip(
        "ultralytics.data.utils", reason="ultralytics with torch and torchvision is not installed"
    )
    scene(tmp_path / "office", ("desk", "person", "tv"), seed=1)
    scene(tmp_path / "pen", ("person", "pig"), seed=2)
    sequences = [str(tmp_path / "office"), str(tmp_path / "pen")]
    assert main(["export-dataset", *sequences, "-o", str(tmp_path / "ds")]) == 0
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    data = utils.check_det_dataset(str(tmp_path / "ds" / "data.yaml"), autodownload=False)
    assert data["nc"] == 81 and data["names"][0] == "person" and data["names"][60] == "dining table"
    found = []
    for part in ("train", "val"):
        images = sorted(str(p) for p in Path(data[part]).iterdir())
        for label in utils.img2label_paths(images):
            found += [int(row.split()[0]) for row in Path(label).read_text().splitlines()]
    assert sorted(set(found)) == [0, 60, 62, 80]
    capsys.readouterr()


# -- detect-eval -------------------------------------------------------------------------------------

COCO_SPELLED = ["--detector", "groundtruth", "--fault", "confusion=desk->dining table:1;tv->tvmonitor:1"]
"""The true boxes as detections, the desk and the tv spelled as COCO and Darknet spell them."""


def test_detect_eval_scores_coco_spellings_of_the_bench_classes_as_hits(tmp_path: Path, capsys):
    """Before, the desk and tv scored recall 0 beside false 'dining table' and 'tvmonitor' rows."""
    scene(tmp_path / "office", ("desk", "person", "tv"))
    assert main(["detect-eval", str(tmp_path / "office"), *COCO_SPELLED, "--min-pixels", "1", "--json"]) == 0
    classes = json.loads(capsys.readouterr().out)["classes"]
    assert set(classes) == {"desk", "person", "tv", "dynamic (any class)"}
    for row in (classes["desk"], classes["tv"], classes["person"]):
        assert (row["truths"], row["true_positives"], row["ap50"]) == (2, 2, 1.0)


def test_detect_eval_matches_an_onnx_model_with_coco_names(tmp_path: Path, capsys):
    from tests.test_detectors import SIZE as MODEL_SIZE
    from tests.test_detectors import _constant_model

    assert MODEL_SIZE == SIZE.width == SIZE.height  # the model's input is the image: no letterbox
    out = np.zeros((1, 6, 84), np.float32)  # YOLOv8 rows: cx cy w h, then one score per class
    for column, (x0, y0, x1, y1) in enumerate((BOXES["desk"], BOXES["tv"])):  # the names' order
        out[0, :4, column] = [(x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0]
        out[0, 4 + column, column] = 0.9
    model = _constant_model(tmp_path / "coco.onnx", out, names="{0: 'dining table', 1: 'tv'}")
    scene(tmp_path / "office", ("desk", "tv"))
    args = ["detect-eval", str(tmp_path / "office"), "--detector", f"onnx:{model}", "--min-pixels", "1"]
    assert main([*args, "--json"]) == 0
    classes = json.loads(capsys.readouterr().out)["classes"]
    assert classes["desk"]["true_positives"] == classes["tv"]["true_positives"] == 2
    assert classes["desk"]["detections"] == classes["tv"]["detections"] == 2


def test_detect_eval_json_prints_the_report_and_o_writes_the_same(tmp_path: Path, capsys):
    scene(tmp_path / "office", ("person",))
    args = ["detect-eval", str(tmp_path / "office"), "--detector", "groundtruth", "--min-pixels", "1"]
    assert main([*args, "--json", "-o", str(tmp_path / "report.json")]) == 0
    printed = json.loads(capsys.readouterr().out)  # stdout is the JSON alone
    assert printed == json.loads((tmp_path / "report.json").read_text())
    assert printed["classes"]["person"]["true_positives"] == 2
    assert main(args) == 0  # the table, no file
    out = capsys.readouterr().out
    assert out.startswith("detector groundtruth on 1 sequence(s)") and "person" in out


# -- refused, one line, exit 2 ------------------------------------------------------------------------


def test_a_names_file_naming_one_class_twice_is_refused(tmp_path: Path, capfd):
    scene(tmp_path / "office", ("desk",))
    (tmp_path / "names.txt").write_text("desk\ndining table\n")
    args = ["export-dataset", str(tmp_path / "office"), "-o", str(tmp_path / "ds"), "--names"]
    assert main([*args, str(tmp_path / "names.txt")]) == 2
    line = one_error_line(capfd.readouterr().err, "names.txt", "'dining table'", "'desk'")
    assert line.startswith("depotbench export-dataset: error: ") and not (tmp_path / "ds").exists()


def test_a_dataset_folder_whose_path_is_not_utf8_is_refused_before_any_work(tmp_path: Path, capfd):
    scene(tmp_path / "office", ("desk",))
    out = tmp_path / os.fsdecode(b"ds-\xff")
    assert main(["export-dataset", str(tmp_path / "office"), "-o", str(out)]) == 2
    one_error_line(capfd.readouterr().err, "not UTF-8", "data.yaml")
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["office"]


def test_the_old_detect_eval_json_file_form_is_refused_naming_the_file(tmp_path: Path, capfd):
    """``--json FILE`` was the file; now FILE is an argument left over, refused before any work."""
    scene(tmp_path / "office", ("person",))
    report = tmp_path / "report.json"
    with pytest.raises(SystemExit) as stop:
        main(["detect-eval", str(tmp_path / "office"), "--detector", "groundtruth", "--json", str(report)])
    assert stop.value.code == 2
    out, err = capfd.readouterr()
    one_error_line(err, "unrecognized arguments", "report.json")
    assert out == "" and not report.exists()
