"""Detectors: exact fault injection, ONNX decoding on tiny known models, NMS, evaluation, export."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.detectors.base import DetectorFrame
from depotbench.detectors.config import DetectorConfig, DetectorKind, OnnxSettings, parse_detector
from depotbench.detectors.detection import Detection, Prior
from depotbench.detectors.faults import Difficulty, Faults, inject, miss_probability
from depotbench.detectors.onnx import OnnxDetector, OnnxModelError, class_wise_nms, recognise_layout
from depotbench.detectors.priors import DEFAULT_PRIORS
from depotbench.eval.detection.evaluate import TruthBox, average_precision, match
from depotbench.eval.run.cache import StageCache
from depotbench.eval.run.detections import detect_sequence

from tests.sequences import write_sequence

IMAGE = (1000, 1000)
BOX = (400.0, 450.0, 500.0, 530.0)  # 100 x 80, far from the border: no clipping
FRAMES, PER_FRAME = 2500, 4  # 10,000 boxes


def _person(box=BOX, confidence: float = 1.0) -> Detection:
    return Detection(box, "person", Prior.DYNAMIC, confidence)


def _frames(n: int = FRAMES, per: int = PER_FRAME, confidence: float = 1.0) -> list[tuple[Detection, ...]]:
    return [tuple(_person(confidence=confidence) for _ in range(per)) for _ in range(n)]


def _within(measured: float, expected: float, std: float) -> None:
    """Within 4 standard errors: fails by chance about once in 16,000 checks."""
    assert abs(measured - expected) <= 4 * std, (measured, expected, std)


def _inject(faults: Faults, frames=None, **kwargs) -> list[tuple[Detection, ...]]:
    return inject(frames if frames is not None else _frames(), faults, IMAGE, DEFAULT_PRIORS, **kwargs)


# -- fault injection: measured against the configured values over 10,000 boxes --------


def test_miss_rate_matches_the_setting():
    p = 0.3
    out = _inject(Faults(miss=p))
    n = FRAMES * PER_FRAME
    kept = sum(len(f) for f in out)
    _within(1 - kept / n, p, np.sqrt(p * (1 - p) / n))


def test_jitter_and_scale_bias_match_the_setting():
    jitter, scale = 0.05, 1.2
    out = _inject(Faults(jitter=jitter, scale=scale))
    boxes = np.array([d.box_xyxy for f in out for d in f])
    n = len(boxes)
    assert n == FRAMES * PER_FRAME  # jitter never removes a box this far inside the image
    w, h = (BOX[2] - BOX[0]) * scale, (BOX[3] - BOX[1]) * scale
    cx = (BOX[0] + BOX[2]) / 2
    x0_error = (boxes[:, 0] - (cx - w / 2)) / w
    y1_error = (boxes[:, 3] - ((BOX[1] + BOX[3]) / 2 + h / 2)) / h
    for error in (x0_error, y1_error):
        _within(error.mean(), 0.0, jitter / np.sqrt(n))
        _within(error.std(), jitter, jitter / np.sqrt(2 * n))
    widths = boxes[:, 2] - boxes[:, 0]
    _within(widths.mean() / (BOX[2] - BOX[0]), scale, scale * jitter * np.sqrt(2) / np.sqrt(n))


def test_false_positive_rate_matches_the_setting():
    rate = 0.5
    out = _inject(Faults(false_positives=rate), frames=[()] * FRAMES * 4)
    counts = np.array([len(f) for f in out])
    _within(counts.mean(), rate, np.sqrt(rate / len(counts)))
    boxes = np.array([d.box_xyxy for f in out for d in f])
    assert (boxes[:, :2] >= 0).all() and (boxes[:, 2] <= IMAGE[0]).all() and (boxes[:, 3] <= IMAGE[1]).all()
    assert {d.class_name for f in out for d in f} == {"person"}


def test_class_confusion_matches_the_table_and_takes_the_new_prior():
    out = _inject(Faults(confusion=(("person", "teddy bear", 0.2), ("person", "dog", 0.1))))
    names = [d for f in out for d in f]
    n = len(names)
    for cls, p in (("teddy bear", 0.2), ("dog", 0.1)):
        _within(sum(d.class_name == cls for d in names) / n, p, np.sqrt(p * (1 - p) / n))
    assert {d.prior for d in names if d.class_name == "teddy bear"} == {Prior.STATIC}
    assert {d.prior for d in names if d.class_name == "dog"} == {Prior.DYNAMIC}


def test_latency_shifts_boxes_by_exactly_k_frames():
    frames = [(_person((10.0 + i, 10.0, 50.0 + i, 60.0)),) for i in range(50)]
    out = _inject(Faults(latency=2), frames=frames)
    assert out[0] == () and out[1] == ()
    assert all(out[i] == frames[i - 2] for i in range(2, 50))


def test_every_nth_frame_holds_boxes_and_drop_empties_frames():
    frames = [(_person((10.0 + i, 10.0, 50.0 + i, 60.0)),) for i in range(30)]
    out = _inject(Faults(every=4), frames=frames)
    assert all(out[i] == frames[i - i % 4] for i in range(30))
    p = 0.25
    dropped = _inject(Faults(drop=p))
    rate = np.mean([len(f) == 0 for f in dropped])
    _within(rate, p, np.sqrt(p * (1 - p) / FRAMES))


def test_confidence_noise_matches_the_setting():
    sigma = 0.05
    out = _inject(Faults(confidence_noise=sigma), frames=_frames(confidence=0.5))
    conf = np.array([d.confidence for f in out for d in f])
    _within(conf.mean(), 0.5, sigma / np.sqrt(len(conf)))
    _within(conf.std(), sigma, sigma / np.sqrt(2 * len(conf)))


def test_small_occluded_and_moving_objects_are_missed_at_the_combined_rate():
    faults = Faults(miss=0.1, miss_small=0.3, miss_occluded=0.4, miss_blurred=0.5, blur_px=20.0)
    hard = Difficulty(area_px=500.0, occlusion=0.5, speed_px=10.0)
    expected = 1 - 0.9 * 0.7 * (1 - 0.4 * 0.5) * (1 - 0.5 * 0.5)
    assert miss_probability(faults, hard) == pytest.approx(expected)
    assert miss_probability(faults, Difficulty(5000.0, 0.0, 0.0)) == pytest.approx(0.1)
    difficulties = [(hard,) * PER_FRAME] * FRAMES
    out = _inject(faults, difficulties=difficulties)
    n = FRAMES * PER_FRAME
    _within(1 - sum(len(f) for f in out) / n, expected, np.sqrt(expected * (1 - expected) / n))


def test_faults_are_seeded_per_frame_and_independent_of_each_other():
    faults = Faults(miss=0.3, jitter=0.05, false_positives=0.2)
    assert _inject(faults) == _inject(faults)  # deterministic
    assert _inject(faults) != _inject(Faults(miss=0.3, jitter=0.05, false_positives=0.2, seed=1))
    assert _inject(faults, sequence_seed=5) != _inject(faults)
    # A frame's faults do not depend on the other frames.
    assert _inject(faults, frames=_frames(100))[:100] == _inject(faults)[:100]
    # Turning jitter up does not change which boxes are missed.
    kept = [len(f) for f in _inject(Faults(miss=0.3))]
    assert kept == [len(f) for f in _inject(Faults(miss=0.3, jitter=0.05, scale=1.3))]


def test_no_fault_is_the_identity():
    frames = _frames(10)
    assert _inject(Faults(), frames=frames) == frames


# -- configuration ---------------------------------------------------------------------


def test_detector_words_parse_into_a_typed_configuration():
    config = parse_detector("groundtruth", faults={"miss": "0.3", "latency": "2"})
    assert config.kind is DetectorKind.GROUNDTRUTH and config.faults == Faults(miss=0.3, latency=2)
    assert config.label == "groundtruth+miss=0.3,latency=2" and config.base().faults == Faults()
    onnx = parse_detector("onnx", settings={"confidence": "0.5", "threads": "2"})
    assert onnx.onnx == OnnxSettings(confidence=0.5, threads=2) and onnx.label == "onnx:yolox_nano"
    assert parse_detector("onnx:/x/m.onnx").model == Path("/x/m.onnx")
    table = parse_detector("onnx", priors={"teddy bear": "dynamic"}).priors
    assert table.prior("teddy bear") is Prior.DYNAMIC and table.prior("chair") is Prior.POTENTIAL
    # The cache key follows what shapes the boxes, not the faults (applied after the cache).
    assert DetectorConfig().key() == config.base().key() != onnx.key()


# -- ONNX decoding on tiny models whose outputs are known --------------------------------

SIZE = 64  # cells: 8x8 + 4x4 + 2x2 = 84


def _constant_model(path: Path, output: np.ndarray, names: str | None = None) -> Path:
    """A model that ignores its image and returns ``output`` (0 * sum(image) keeps the input used)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    graph = helper.make_graph(
        [
            helper.make_node("ReduceSum", ["images"], ["s"], keepdims=0),
            helper.make_node("Mul", ["s", "zero"], ["z"]),
            helper.make_node("Add", ["const", "z"], ["output"]),
        ],
        "constant",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, SIZE, SIZE])],
        [helper.make_tensor_value_info("output", TensorProto.FLOAT, list(output.shape))],
        [
            numpy_helper.from_array(output.astype(np.float32), "const"),
            numpy_helper.from_array(np.zeros((), np.float32), "zero"),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    if names is not None:
        helper.set_model_props(model, {"names": names})
    onnx.save(model, str(path))
    return path


def _names_file(tmp_path: Path) -> str:
    path = tmp_path / "names.txt"
    path.write_text("person\ndog\n")
    return str(path)


def _detect(model: Path, image_wh: tuple[int, int], **settings) -> tuple[Detection, ...]:
    detector = OnnxDetector(model, OnnxSettings(**settings))
    rgb = np.zeros((image_wh[1], image_wh[0], 3), np.uint8)
    return detector.detect(DetectorFrame(0, 0.0, rgb))


def test_yolox_raw_grid_outputs_are_decoded_and_mapped_back(tmp_path: Path):
    out = np.zeros((1, 84, 7), np.float32)
    out[0, :, 4] = 0.0
    # Stride-8 cell (x=3, y=2) is row 2*8+3: centre (3.5, 2.5)*8, w = 2*8, h = 3*8 -> (20,8)-(36,32).
    out[0, 19] = [0.5, 0.5, np.log(2.0), np.log(3.0), 0.9, 0.1, 0.8]
    # The same box a little lower scoring: suppressed by NMS (same class).
    out[0, 20] = [-0.5, 0.5, np.log(2.0), np.log(3.0), 0.8, 0.1, 0.8]
    # The same place, the other class: kept (class-wise NMS).
    out[0, 27] = [0.5, -0.5, np.log(2.0), np.log(3.0), 0.9, 0.7, 0.1]
    model = _constant_model(tmp_path / "yolox.onnx", out)
    detector = OnnxDetector(model, OnnxSettings(names=_names_file(tmp_path)))
    assert detector.layout == "yolox"
    found = detector.detect(DetectorFrame(0, 0.0, np.zeros((128, 128, 3), np.uint8)))  # scale 0.5
    assert [d.class_name for d in found] == ["dog", "person"]
    dog, person = found
    assert dog.box_xyxy == pytest.approx((40.0, 16.0, 72.0, 64.0))
    assert dog.confidence == pytest.approx(0.72) and dog.prior is Prior.DYNAMIC
    assert person.box_xyxy == pytest.approx((40.0, 16.0, 72.0, 64.0))
    assert person.confidence == pytest.approx(0.63)


def test_yolov5_rows_are_in_input_pixels_and_letterboxed_centred(tmp_path: Path):
    out = np.zeros((1, 3 * 84, 7), np.float32)
    out[0, 100] = [32.0, 32.0, 16.0, 8.0, 0.8, 0.9, 0.2]  # person, score 0.72
    out[0, 101] = [10.0, 10.0, 4.0, 4.0, 0.2, 0.9, 0.2]  # score 0.18: below the threshold
    model = _constant_model(tmp_path / "v5.onnx", out)
    assert OnnxDetector(model, OnnxSettings(names=_names_file(tmp_path))).layout == "yolov5"
    # A 128 x 64 image fits as 64 x 32 with 16 px of grey above and below.
    (person,) = _detect(model, (128, 64), names=_names_file(tmp_path))
    assert person.class_name == "person" and person.confidence == pytest.approx(0.72)
    assert person.box_xyxy == pytest.approx((48.0, 24.0, 80.0, 40.0))


def test_yolov8_channels_first_without_objectness_with_names_from_metadata(tmp_path: Path):
    out = np.zeros((1, 6, 84), np.float32)
    out[0, :, 5] = [32.0, 32.0, 20.0, 10.0, 0.1, 0.95]
    model = _constant_model(tmp_path / "v8.onnx", out, names="{0: 'person', 1: 'pig'}")
    detector = OnnxDetector(model)
    assert detector.layout == "yolov8" and detector.names == ["person", "pig"]
    (pig,) = _detect(model, (64, 64))
    assert pig.class_name == "pig" and pig.confidence == pytest.approx(0.95)
    assert pig.box_xyxy == pytest.approx((22.0, 27.0, 42.0, 37.0))


def test_darknet_spellings_become_the_bench_class_names(tmp_path: Path):
    """The shipped coco.names says 'tvmonitor' and 'diningtable': without the aliases a
    detected screen or desk was a static unknown class and never matched the truth."""
    out = np.zeros((1, 6, 84), np.float32)
    model = _constant_model(tmp_path / "v8.onnx", out, names="{0: 'tvmonitor', 1: 'diningtable'}")
    detector = OnnxDetector(model)
    assert detector.names == ["tv", "desk"]
    assert [DEFAULT_PRIORS.prior(n) for n in detector.names] == [Prior.POTENTIAL, Prior.POTENTIAL]


def test_unknown_layouts_are_refused_by_name():
    assert recognise_layout((1, 3549, 85), (416, 416)) == "yolox"
    assert recognise_layout((1, 84, 8400), (640, 640)) == "yolov8"
    assert recognise_layout((1, 25200, 85), (640, 640)) == "yolov5"
    with pytest.raises(OnnxModelError, match="matches no YOLO layout"):
        recognise_layout((1, 1000, 85), (640, 640))
    with pytest.raises(OnnxModelError, match="expected 1 x N"):
        recognise_layout((1000, 85), (640, 640))


def test_class_wise_nms_against_a_hand_worked_case():
    boxes = np.array(
        [
            [0, 0, 10, 10],  # A: 0.9, class 0: kept
            [1, 1, 11, 11],  # B: 0.8, class 0, IoU(A) = 81/119 = 0.68 > 0.45: suppressed
            [1, 1, 11, 11],  # C: 0.7, class 1: kept (another class)
            [20, 20, 30, 30],  # D: 0.6, class 0, apart: kept
            [0, 0, 10, 10],  # E: 0.2: under the score threshold
            [5, 0, 15, 10],  # F: 0.5, class 0, IoU(A) = 50/150 = 0.33 < 0.45: kept
        ],
        float,
    )
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.2, 0.5])
    classes = np.array([0, 0, 1, 0, 0, 0])
    assert class_wise_nms(boxes, scores, classes, 0.3, 0.45).tolist() == [0, 2, 3, 5]


# -- detector evaluation ---------------------------------------------------------------


def _truth(box, cls="person") -> TruthBox:
    return TruthBox(box, cls, Prior.DYNAMIC, Difficulty(1e4, 0.0, 0.0), False)


def test_matching_is_greedy_by_confidence_with_iou_half():
    truths = [_truth((0, 0, 10, 10)), _truth((20, 0, 30, 10))]
    detections = [
        _person((0.0, 0.0, 10.0, 9.0), 0.6),  # IoU 0.9 with truth 0, but lower confidence
        _person((0.0, 0.0, 10.0, 10.0), 0.9),  # takes truth 0 first
        _person((20.0, 0.0, 25.0, 10.0), 0.8),  # IoU 0.5 with truth 1: a match
    ]
    matched, taken = match(detections, truths)
    assert matched.tolist() == [-1, 0, 1] and taken.tolist() == [True, True]


def test_ap50_agrees_with_pycocotools():
    pytest.importorskip("pycocotools")
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    rng = np.random.default_rng(4)
    images, annotations, results = [], [], []
    scores, hits, truths = [], [], 0
    for image_id in range(1, 41):
        images.append({"id": image_id, "width": 640, "height": 480})
        gt = []
        for _ in range(rng.integers(0, 4)):
            x, y = rng.uniform(0, 500, 2)
            w, h = rng.uniform(40, 120, 2)
            gt.append((x, y, x + w, y + h))
            annotations.append(
                {
                    "id": len(annotations) + 1,
                    "image_id": image_id,
                    "category_id": 1,
                    "bbox": [x, y, w, h],
                    "area": w * h,
                    "iscrowd": 0,
                }
            )
        dets = []
        for box in gt:
            if rng.random() < 0.8:  # found, with some error
                x0, y0, x1, y1 = np.array(box) + rng.normal(0, 8, 4)
                dets.append(_person((x0, y0, x1, y1), float(rng.uniform(0.3, 1.0))))
        for _ in range(rng.integers(0, 2)):  # false positives
            x, y = rng.uniform(0, 500, 2)
            dets.append(_person((x, y, x + 60, y + 60), float(rng.uniform(0.3, 1.0))))
        for d in dets:
            x0, y0, x1, y1 = d.box_xyxy
            results.append(
                {
                    "image_id": image_id,
                    "category_id": 1,
                    "bbox": [x0, y0, x1 - x0, y1 - y0],
                    "score": d.confidence,
                }
            )
        matched, _ = match(dets, [_truth(b) for b in gt])
        scores += [d.confidence for d in dets]
        hits += [m >= 0 for m in matched]
        truths += len(gt)
    coco = COCO()
    coco.dataset = {"images": images, "annotations": annotations, "categories": [{"id": 1, "name": "person"}]}
    coco.createIndex()
    evaluation = COCOeval(coco, coco.loadRes(results), "bbox")
    evaluation.params.iouThrs = np.array([0.5])
    evaluation.params.areaRng = [[0, 1e10]]
    evaluation.params.areaRngLbl = ["all"]
    evaluation.params.maxDets = [100]
    evaluation.evaluate()
    evaluation.accumulate()
    reference = float(evaluation.eval["precision"][0, :, 0, 0, 0].mean())
    ours = average_precision(np.array(scores), np.array(hits), truths)
    assert ours == pytest.approx(reference, abs=1e-9)


# -- the cache and the harness -----------------------------------------------------------


def test_detections_are_cached_per_sequence_and_detector_and_invalidated_by_an_edit(tmp_path: Path):
    write_sequence(tmp_path / "seq", n=4, with_flow=False)
    from depotbench.sim.sequence import Sequence

    cache = StageCache(tmp_path / "cache")
    sequence = Sequence.open(tmp_path / "seq")
    first = detect_sequence(sequence, DetectorConfig(), cache)
    assert not first.from_cache and first.per_frame[0][0].class_name == "person"
    again = detect_sequence(sequence, parse_detector("groundtruth", faults={"miss": "0.5"}), cache)
    assert again.from_cache  # faults go on top of the cached boxes
    assert detect_sequence(sequence, DetectorConfig(), cache).per_frame == first.per_frame
    other = detect_sequence(sequence, DetectorConfig(min_visible_pixels=500), cache)
    assert not other.from_cache and other.per_frame[0] == ()
    rgb = sequence.frames[2].rgb_path
    os.utime(rgb, ns=(rgb.stat().st_atime_ns, rgb.stat().st_mtime_ns + 10**9))
    assert detect_sequence(Sequence.open(tmp_path / "seq"), DetectorConfig(), cache).from_cache  # same bytes
    image = cv2.imread(str(rgb))
    image[0, 0] ^= 1
    cv2.imwrite(str(rgb), image)
    assert not detect_sequence(Sequence.open(tmp_path / "seq"), DetectorConfig(), cache).from_cache


def test_the_cache_evicts_least_recently_used_entries(tmp_path: Path):
    cache = StageCache(tmp_path / "cache", max_bytes=2500)
    aaa, bbb, ccc, ddd = ("a" * 32, "b" * 32, "c" * 32, "d" * 32)  # keys are 32 hexadecimal digits
    for i, key in enumerate((aaa, bbb, ccc)):
        cache.put("stage", key, bytes(1000))
        os.utime(tmp_path / "cache" / "stage" / key, (100.0 + i, 100.0 + i))
    # Three entries would exceed the bound: putting the third evicted the oldest.
    assert cache.get("stage", aaa) is None and cache.get("stage", bbb) is not None
    cache.put("stage", ddd, bytes(1000))  # bbb was just used: ccc goes
    assert cache.get("stage", ccc) is None
    assert cache.get("stage", bbb) is not None and cache.get("stage", ddd) is not None
    assert cache.size_bytes() <= 2500


def test_export_writes_yolo_labels_and_coco_json_split_by_sequence(tmp_path: Path, capsys):
    from depotbench.eval.cli.main import main

    for name, seed in (("a", 0), ("b", 1), ("c", 2)):
        write_sequence(tmp_path / name, n=3, seed=seed, with_flow=False)
    args = ["export-dataset", *(str(tmp_path / n) for n in "abc"), "-o", str(tmp_path / "ds"), "--val", "b"]
    assert main([*args, "--min-pixels", "10"]) == 0
    splits = json.loads((tmp_path / "ds" / "splits.json").read_text())
    assert splits["splits"] == {"a": "train", "b": "val", "c": "train"}
    assert splits["ids"] == {"chair": 56, "person": 0} and len(splits["classes"]) == 81  # COCO's, then pig
    # The person's visible box (30, 10)-(40, 20) in a 64 x 48 image.
    label = (tmp_path / "ds" / "labels" / "val" / "b_1.000000.txt").read_text().split()
    assert label[0] == "0"  # COCO's id of person; the chair is never visible
    assert [float(v) for v in label[1:]] == pytest.approx([35 / 64, 15 / 48, 10 / 64, 10 / 48], abs=1e-6)
    assert (tmp_path / "ds" / "images" / "val" / "b_1.000000.png").read_bytes() == (
        tmp_path / "b" / "rgb" / "1.000000.png"
    ).read_bytes()
    coco = json.loads((tmp_path / "ds" / "annotations" / "instances_train.json").read_text())
    assert len(coco["images"]) == 6 and len(coco["annotations"]) == 6
    assert coco["annotations"][0]["bbox"] == [30, 10, 10, 10] and coco["annotations"][0]["category_id"] == 1
    assert coco["categories"][0] == {"id": 1, "name": "person"} and len(coco["categories"]) == 81
    assert "\n  0: person\n" in (tmp_path / "ds" / "data.yaml").read_text()
    seeded = [*args[:-2], "-o", str(tmp_path / "ds2"), "--seed", "3", "--val-fraction", "0.3"]
    assert main(seeded) == 0
    parts = json.loads((tmp_path / "ds2" / "splits.json").read_text())["splits"]
    assert sorted(parts.values()) == ["train", "train", "val"]  # one of three, by sequence
    assert main([*seeded[:-4], "-o", str(tmp_path / "ds3"), "--seed", "3", "--val-fraction", "0.3"]) == 0
    assert json.loads((tmp_path / "ds3" / "splits.json").read_text())["splits"] == parts  # seeded
    capsys.readouterr()


# -- the shipped YOLOX-nano on frames the bench renders -----------------------------------

ONE_PERSON = """\
name: one_person
description: One whole, unoccluded person walking across in front of a still camera.
seed: 3
frames: 12
actors:
  - {kind: person, count: 1, speed_mps: [0.5, 0.5], waypoints: [[-0.4, -0.6], [0.4, -0.6]]}
camera: {motion: static, position_m: [0.0, -3.6, 1.2], target_m: [0.0, 1.5, 1.0]}
"""


@pytest.fixture(scope="module")
def one_person(tmp_path_factory) -> Path:
    from depotbench.scenes.schema import load_scenario, to_scenario
    from depotbench.sim.generate import generate

    root = tmp_path_factory.mktemp("one_person")
    (root / "one.yaml").write_text(ONE_PERSON)
    return generate(to_scenario(load_scenario(root / "one.yaml")), root / "seq", progress=False)


@pytest.mark.render
def test_the_shipped_model_finds_the_rendered_person(one_person: Path):
    from depotbench.detectors.config import SHIPPED_MODEL
    from depotbench.detectors.groundtruth import GroundTruthDetector, truncated
    from depotbench.eval.detection.evaluate import iou_matrix
    from depotbench.sim.sequence import Sequence

    sequence = Sequence.open(one_person)
    truth = GroundTruthDetector(sequence)
    detector = OnnxDetector(SHIPPED_MODEL)
    assert detector.layout == "yolox" and len(detector.names) == 80
    for i in (0, len(sequence) - 1):
        (person,) = [o for o in truth.visible(i) if o.class_name == "person"]
        assert not truncated(person.box_xyxy, 640, 480) and person.visible_pixels > 5000
        found = [
            d for d in detector.detect(DetectorFrame(i, 0.0, sequence.rgb(i))) if d.class_name == "person"
        ]
        assert found, f"frame {i}: no person found"
        best = iou_matrix(np.array([person.box_xyxy], float), np.array([d.box_xyxy for d in found])).max()
        assert best >= 0.5 and found[0].prior is Prior.DYNAMIC  # a match by COCO's criterion


@pytest.mark.render
def test_run_with_the_onnx_detector_works_with_every_strategy(one_person: Path, tmp_path: Path, capsys):
    from depotbench.eval.cli.main import main
    from depotbench.eval.run.harness import STRATEGY_CHOICES

    for strategy in STRATEGY_CHOICES:
        out = tmp_path / strategy
        assert (
            main(["run", str(one_person), "-o", str(out), "--strategy", strategy, "--detector", "onnx"]) == 0
        )
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics["detector"] == "onnx:yolox_nano" and metrics["tracked_frames"] == 12
        assert metrics["detector_config"]["model_sha256"].startswith("c789161e")
        # Only the first run ran the network; the others read its boxes from the cache.
        assert metrics["detector_time"]["cached"] is (strategy != STRATEGY_CHOICES[0])
        if strategy in ("box_rule", "prior_flow", "box_epipolar_flow"):
            assert metrics["rejection"]["rejected_keypoints"] > 0
    assert "onnx:yolox_nano" in (tmp_path / "none" / "trajectory.txt").read_text().splitlines()[0]
    capsys.readouterr()


@pytest.fixture(scope="module")
def animal_sightings(tmp_path_factory) -> dict[str, list[tuple[bool, bool]]]:
    """dog_and_cat_roaming's seeds 1-3, their first 40 frames, through the shipped model
    by recognition.py's rule: per class ("dog", "cat"), one (found, cut by the image
    edge) per sighting of >= 2000 visible px, found when a box of that class at
    confidence 0.3 overlaps the true visible box at IoU >= 0.5."""
    from depotbench.detectors.config import SHIPPED_MODEL
    from depotbench.eval.detection.evaluate import iou_matrix
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate
    from depotbench.sim.sequence import Sequence

    root = tmp_path_factory.mktemp("animals")
    detector = OnnxDetector(SHIPPED_MODEL)
    sightings: dict[str, list[tuple[bool, bool]]] = {"dog": [], "cat": []}
    for seed in (1, 2, 3):
        scenario = library.get("dog_and_cat_roaming").model_copy(
            update={"seed": seed, "frames": 40, "duration_s": None}
        )
        sequence = Sequence.open(generate(to_scenario(scenario), root / f"s{seed}", progress=False))
        animal = {i["instance_id"]: i["class_name"] for i in sequence.meta["instances"]}
        for index, objects in enumerate(sequence.objects()):
            truths = [o for o in objects if animal[o.instance_id] in sightings and o.visible_pixels >= 2000]
            if not truths:
                continue
            detections = detector.detect(DetectorFrame(index, 0.0, sequence.rgb(index)))
            for truth in truths:
                found = [d.box_xyxy for d in detections if d.class_name == truth.class_name]
                ious = iou_matrix(np.array([truth.box_xyxy], float), np.array(found, float).reshape(-1, 4))
                sightings[truth.class_name].append((bool((ious >= 0.5).any()), bool(truth.truncated)))
    return sightings


# The animal-recognition guards: 27 s of CPU in the default run (three 40-frame animal
# scenes and 120 detections); the shipped model's reading of a rendered scene stays there
# (test_the_shipped_model_finds_the_rendered_person), and the animal scenes render there in
# tests/test_example_trackers.py.
@pytest.mark.slow
@pytest.mark.render
def test_the_shipped_model_takes_the_animal_scenes_cats_for_cats(animal_sightings):
    """The cats' coat and build are what made them cats to a COCO detector (0.11 of
    sightings with drawn stripes, 0.53 with the photographed fur, 0.63 with a stockier
    body and larger head, 0.87 with the fur laid on along the body; docs/recognition.md). A
    regression guard: drawn coats gave 17 of 120 here (version 0.3.4), the photographed
    fur on the slim cat 62 of 120, the stocky cat 72 of 120, the fur laid on (0.3.8) 92
    of 120, 96 of 120 with 0.3.14 and 98 of 120 with 0.3.15's loops; the floor is 0.7."""
    cats = animal_sightings["cat"]
    hits = sum(found for found, _ in cats)
    assert len(cats) >= 100
    assert hits / len(cats) >= 0.7, (hits, len(cats))


@pytest.mark.slow  # beside the cats-for-cats guard, on the same sightings
@pytest.mark.render
def test_the_shipped_model_takes_the_animal_scenes_dogs_for_dogs(animal_sightings):
    """A regression guard for the dog's look (coat, tail, legs; docs/recognition.md):
    117 of 120 sightings here with version 0.3.15, 118 of 120 with 0.3.14's wider loop;
    over seeds 1-240, 0.84 of sightings (docs/recognition.md)."""
    dogs = animal_sightings["dog"]
    hits = sum(found for found, _ in dogs)
    assert len(dogs) >= 100
    assert hits / len(dogs) >= 0.8, (hits, len(dogs))


@pytest.mark.slow  # 12 s; beside the animal-recognition guards
@pytest.mark.render
def test_the_animal_scenes_dog_and_cat_are_seen_whole_in_most_sightings(tmp_path: Path):
    """Issue 14 asks for dogs and cats "at such sizes in the animal scenes" that a
    detector can find them. Whole, they are found in about nine sightings of ten; cut by
    the image edge (a rump, a chest) in six or seven (docs/recognition.md). Their loops
    ran past the view's edges (the dog's to x = +-1.9 m where its near leg sees +-1.4 m),
    so nearly half their sightings were cut; now they turn about at the edges. Over
    seeds 1-4's whole 10 s, sampled at 3 frames/s at 320x240 (truncation depends on the
    field of view, not the size; sightings of >= 500 px, 2000 at 640x480), 0.3.14 cut
    52 of 108 dog sightings and 51 of 119 cat sightings; 0.3.15 cuts 43 of 120 and 22 of
    120. The ground truth's own truncation flag is the measure: no detector involved."""
    import dataclasses

    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate
    from depotbench.sim.sequence import Sequence

    sightings = {"dog": [0, 0], "cat": [0, 0]}  # [sightings, cut by the edge]
    for seed in (1, 2, 3, 4):
        scenario = to_scenario(
            library.get("dog_and_cat_roaming").model_copy(update={"seed": seed, "fps": 3.0})
        )
        scenario = dataclasses.replace(scenario, width=320, height=240, focal_px=525.0 / 2)
        sequence = Sequence.open(generate(scenario, tmp_path / f"s{seed}", progress=False))
        kind = {i["instance_id"]: i["class_name"] for i in sequence.meta["instances"]}
        for objects in sequence.objects():
            for o in objects:
                if kind[o.instance_id] in sightings and o.visible_pixels >= 500:
                    sightings[kind[o.instance_id]][0] += 1
                    sightings[kind[o.instance_id]][1] += bool(o.truncated)
    (dogs, dogs_cut), (cats, cats_cut) = sightings["dog"], sightings["cat"]
    assert dogs >= 100 and cats >= 100, sightings
    assert dogs_cut / dogs <= 0.4 and cats_cut / cats <= 0.3, sightings
