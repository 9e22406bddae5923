"""Hostile ONNX models and class tables: each is refused in one line naming the file, or read safely.

The models are tiny: a constant output of a chosen shape and values (inf, a short class
table, a 0x0 or 65536x65536 declared input), built with ``onnx`` like the probe's mk.py
(/work/shared/reliability-probe.md, C1-C4, M9, M11). Each case runs the real CLI in-process
and expects exit 2 and exactly one line on stderr, no traceback; the ones that would
allocate without bound run in a child with an address-space cap.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import depotbench.detectors.config as dconfig
import depotbench.detectors.onnx as donnx
import numpy as np
import pytest
from depotbench.core.errors import InputError
from depotbench.detectors.base import DetectorFrame
from depotbench.detectors.config import SHIPPED_MODEL, OnnxSettings
from depotbench.detectors.onnx import OnnxDetector, OnnxModelError
from depotbench.eval.cli.main import main

from tests.capped import MAX_RSS_MB, peak_rss_mb
from tests.sequences import write_sequence

onnx = pytest.importorskip("onnx")

TWO = "{0: 'person', 1: 'dog'}"
CELLS_32 = 21  # a 32x32 input: 4x4 + 2x2 + 1x1 cells at strides 8, 16, 32


def model(
    path: Path,
    out: np.ndarray,
    hw: tuple[int | str, int | str] = (32, 32),
    names: str | None = TWO,
    symbolic: bool = False,
) -> Path:
    """A model that ignores its image and returns ``out``. ``symbolic``: its output shape is
    computed from the image (0 x its sum, added to the shape), so ONNX Runtime knows it only
    when it runs."""
    from onnx import TensorProto, helper, numpy_helper

    nodes = [
        helper.make_node("ReduceSum", ["images"], ["s"], keepdims=0),
        helper.make_node("Mul", ["s", "zero"], ["z"]),
    ]
    const = out.astype(np.float32)
    if symbolic:
        const = const.ravel()
        nodes += [
            helper.make_node("Cast", ["z"], ["zi"], to=TensorProto.INT64),
            helper.make_node("Add", ["shape", "zi"], ["runtime_shape"]),
            helper.make_node("Reshape", ["const", "runtime_shape"], ["output"]),
        ]
    else:
        nodes.append(helper.make_node("Add", ["const", "z"], ["output"]))
    graph = helper.make_graph(
        nodes,
        "constant",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, *hw])],
        [
            helper.make_tensor_value_info(
                "output", TensorProto.FLOAT, ["b", "c", "n"] if symbolic else out.shape
            )
        ],
        [
            numpy_helper.from_array(const, "const"),
            numpy_helper.from_array(np.zeros((), np.float32), "zero"),
            numpy_helper.from_array(np.array(out.shape, np.int64), "shape"),
        ],
    )
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    proto.ir_version = 8
    if names is not None:
        helper.set_model_props(proto, {"names": names})
    onnx.save(proto, str(path))
    return path


def v8_output(cls: int = 1, score: float = 0.9, classes: int = 2) -> np.ndarray:
    """YOLOv8 rows (1 x (4+C) x 21): one box of class ``cls`` in the middle of a 32x32 input."""
    out = np.zeros((1, 4 + classes, CELLS_32), np.float32)
    out[0, :4, 5] = [16.0, 16.0, 8.0, 8.0]
    out[0, 4 + cls, 5] = score
    return out


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("hostile") / "seq"
    write_sequence(root, n=3, with_flow=False)
    return root


def run(seq: Path, out: Path, detector: str, *settings: str) -> list[str]:
    args = ["run", str(seq), "-o", str(out), "--strategy", "box_rule", "--detector", detector]
    for item in settings:
        args += ["--detector-set", item]
    return args


def refused(capfd, args: list[str], *needles: str) -> str:
    """Exit 2 and one line naming every needle, no traceback; the line."""
    code = main(args)
    err = capfd.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, (code, err)
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def accepted(capfd, args: list[str]) -> None:
    code = main(args)
    err = capfd.readouterr().err
    assert code == 0 and "Traceback" not in err, (code, err)


def detect(path: Path, **settings) -> tuple:
    detector = OnnxDetector(path, OnnxSettings(**settings))
    return detector.detect(DetectorFrame(0, 0.0, np.zeros((32, 32, 3), np.uint8)))


# -- C1: a class table shorter than the model's classes ---------------------------------------------


def test_model_errors_are_input_errors():
    """So a model's fault is one line wherever it is raised (load or detection)."""
    assert issubclass(OnnxModelError, InputError)


def test_a_names_file_shorter_than_the_models_classes_is_refused_at_load(seq, tmp_path, capfd):
    one = tmp_path / "one.txt"
    one.write_text("person\n")
    v8 = model(tmp_path / "v8.onnx", v8_output())
    with pytest.raises(OnnxModelError, match="2 classes"):
        OnnxDetector(v8, OnnxSettings(names=str(one)))
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{v8}", f"names={one}"), str(v8), str(one), "2 classes")


def test_a_long_file_of_other_lines_is_still_too_short_for_the_shipped_model(seq, tmp_path, capfd):
    """The probe's names=/etc/passwd: 25 lines for 80 classes."""
    passwd = tmp_path / "passwd"
    passwd.write_text("".join(f"user{i}:x:{i}:{i}::/home:/bin/sh\n" for i in range(25)))
    line = refused(capfd, run(seq, tmp_path / "o1", "onnx", f"names={passwd}"), str(passwd), "80 classes")
    assert str(SHIPPED_MODEL) in line


def test_metadata_with_fewer_names_than_classes_is_refused_at_load(seq, tmp_path, capfd):
    v8 = model(tmp_path / "v8.onnx", v8_output(), names="{0: 'person'}")
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{v8}"), str(v8), "metadata", "2 classes")


def test_a_short_table_is_found_at_detection_when_the_output_shape_is_symbolic(seq, tmp_path, capfd):
    """With layout= given and a symbolic output, the class count is known only once it runs."""
    v8 = model(tmp_path / "v8.onnx", v8_output(), names="{0: 'person'}", symbolic=True)
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{v8}", "layout=yolov8"), str(v8), "metadata", "class 1")


def test_a_symbolic_output_is_run_once_at_load_when_the_layout_is_recognised(seq, tmp_path, capfd):
    v8 = model(tmp_path / "v8.onnx", v8_output(score=0.1), names="{0: 'person'}", symbolic=True)
    with pytest.raises(OnnxModelError, match="2 classes"):
        OnnxDetector(v8)


def test_only_the_boxes_kept_need_a_name(seq, tmp_path, capfd):
    """Class 1 scores 0.1, under the 0.3 threshold: no box of it is kept, so no name is needed."""
    v8 = model(tmp_path / "v8.onnx", v8_output(score=0.1), names="{0: 'person'}", symbolic=True)
    assert detect(v8, layout="yolov8") == ()
    accepted(capfd, run(seq, tmp_path / "o1", f"onnx:{v8}", "layout=yolov8"))


def test_metadata_keys_that_skip_a_class_are_refused(tmp_path):
    """{0: 'person', 5: 'dog'} once made 'dog' the name of class 1."""
    v8 = model(tmp_path / "v8.onnx", v8_output(), names="{0: 'person', 5: 'dog'}")
    with pytest.raises(OnnxModelError, match="0 to 1"):
        OnnxDetector(v8)


# -- C2: non-finite outputs are no boxes -------------------------------------------------------------


@pytest.mark.parametrize(
    "row",
    [
        [np.inf] * 4 + [0.0, 0.9],
        [-np.inf, 16.0, 8.0, 8.0, 0.0, 0.9],
        [16.0, 16.0, np.inf, 8.0, 0.0, 0.9],
        [np.nan, 16.0, 8.0, 8.0, 0.0, 0.9],
        [16.0, 16.0, 8.0, 8.0, 0.0, np.inf],
        [16.0, 16.0, 8.0, 8.0, 0.0, np.nan],
        [3e38, 3e38, 3e38, 3e38, 0.0, 0.9],  # finite in float32, inf once added
    ],
    ids=["box-inf", "box-minus-inf", "width-inf", "box-nan", "score-inf", "score-nan", "box-overflow"],
)
def test_non_finite_outputs_give_no_box(tmp_path, row):
    out = np.zeros((1, 6, CELLS_32), np.float32)
    out[0, :, 5] = row
    out[0, :, 7] = [8.0, 8.0, 4.0, 4.0, 0.8, 0.0]  # a valid person beside it is kept
    (person,) = detect(model(tmp_path / "v8.onnx", out))
    assert person.class_name == "person" and person.box_xyxy == pytest.approx((6.0, 6.0, 10.0, 10.0))


def test_an_all_inf_model_runs_with_no_boxes(seq, tmp_path, capfd):
    """The probe's v8_inf.onnx: ValueError 'box (nan, nan, 160.0, 120.0) must be finite'."""
    out = v8_output(score=0.9)
    out[0, :4] = np.inf
    accepted(capfd, run(seq, tmp_path / "o1", f"onnx:{model(tmp_path / 'v8_inf.onnx', out)}"))


# -- C3 and M9: the declared input size is bounded before anything is allocated ---------------------


def test_a_0x0_input_is_refused_with_an_explicit_layout(seq, tmp_path, capfd):
    zero = model(tmp_path / "zero.onnx", v8_output(), hw=(0, 0))
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{zero}", "layout=yolov8"), str(zero), "0x0")


def test_a_0x0_input_is_named_as_the_problem_when_the_layout_is_recognised(seq, tmp_path, capfd):
    """M9: it said 'matches no YOLO layout ...; set layout= explicitly', naming no file."""
    zero = model(tmp_path / "zero.onnx", v8_output(), hw=(0, 0))
    line = refused(capfd, run(seq, tmp_path / "o1", f"onnx:{zero}"), str(zero), "0x0")
    assert "layout" not in line


def test_an_input_larger_than_the_maximum_is_refused(seq, tmp_path, capfd):
    side = donnx.MAX_INPUT_SIDE + 32
    big = model(tmp_path / "big.onnx", np.zeros((1, 6, 1), np.float32), hw=(side, 32))
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{big}", "layout=yolov8"), str(big), f"32x{side}")


def test_an_unrecognised_layout_names_the_model(seq, tmp_path, capfd):
    odd = model(tmp_path / "odd.onnx", np.zeros((1, 6, 5), np.float32))
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{odd}"), str(odd), "matches no YOLO layout")


@pytest.mark.parametrize(
    "layout, shape",
    [("yolov8", (1, 4, CELLS_32)), ("yolox", (1, 5, 7)), ("yolov5", (1, 5, 5)), ("yolov8", (6, CELLS_32))],
)
def test_an_explicit_layout_that_does_not_fit_the_output_is_one_line(seq, tmp_path, capfd, layout, shape):
    bad = model(tmp_path / "bad.onnx", np.zeros(shape, np.float32))
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{bad}", f"layout={layout}"), str(bad), layout)


def test_a_symbolic_output_that_does_not_fit_the_layout_is_one_line_at_detection(seq, tmp_path, capfd):
    bad = model(tmp_path / "bad.onnx", np.zeros((1, 4, CELLS_32), np.float32), symbolic=True)
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{bad}", "layout=yolov8"), str(bad), "yolov8")


def test_a_65536_px_input_is_refused_within_the_memory_bound(tmp_path):
    """The probe's huge_dims.onnx asked for about 22 GB with layout=yolov8."""
    write_sequence(tmp_path / "seq", n=3, with_flow=False)
    huge = model(tmp_path / "huge.onnx", np.zeros((1, 6, 1), np.float32), hw=(65536, 65536))
    code, err, peak = peak_rss_mb(run(tmp_path / "seq", tmp_path / "o1", f"onnx:{huge}", "layout=yolov8"))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert str(huge) in err and "65536x65536" in err
    assert peak < MAX_RSS_MB, peak


# -- C4: the names file is read within a bound ---------------------------------------------------------


def test_names_from_dev_zero_are_refused_within_the_memory_bound(tmp_path):
    write_sequence(tmp_path / "seq", n=3, with_flow=False)
    code, err, peak = peak_rss_mb(run(tmp_path / "seq", tmp_path / "o1", "onnx", "names=/dev/zero"))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert "/dev/zero" in err and "not a regular file" in err
    assert peak < MAX_RSS_MB, peak


def test_an_oversized_names_file_is_refused_by_its_size(seq, tmp_path, capfd):
    big = tmp_path / "names.txt"
    with big.open("wb") as handle:
        handle.truncate(1 << 20)
    refused(capfd, run(seq, tmp_path / "o1", "onnx", f"names={big}"), str(big), "limit")


def test_a_missing_names_file_is_one_line(seq, tmp_path, capfd):
    refused(capfd, run(seq, tmp_path / "o1", "onnx", f"names={tmp_path}/no.txt"), "no.txt", "does not exist")


# -- M9 and M11: the model file is a regular file of bounded size -------------------------------------


def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "fifo.onnx"
    os.mkfifo(path)
    return path


def test_a_fifo_model_is_not_a_regular_file_and_opening_it_does_not_block(tmp_path):
    path = fifo(tmp_path)
    for call in (dconfig.check_model_file, dconfig.file_sha256, OnnxDetector):
        with pytest.raises(InputError, match="not a regular file"):
            call(path)


def test_a_fifo_model_is_refused_as_not_a_regular_file(seq, tmp_path, capfd):
    """M9: 'model file models/fifo.onnx does not exist'; it exists but is not a regular file."""
    path = fifo(tmp_path)
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{path}"), str(path), "not a regular file")


def test_a_missing_model_still_does_not_exist(seq, tmp_path, capfd):
    with pytest.raises(InputError, match="does not exist"):
        dconfig.check_model_file(tmp_path / "no.onnx")
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{tmp_path}/no.onnx"), "no.onnx", "does not exist")


def test_an_oversized_model_is_refused_before_it_is_hashed(seq, tmp_path, capfd):
    """M11: a 5 GB sparse 'model' was hashed in full (37 s) before ONNX Runtime refused it."""
    big = tmp_path / "big.onnx"
    with big.open("wb") as handle:
        handle.truncate(dconfig.MAX_MODEL_BYTES + 1)
    started = time.perf_counter()
    refused(capfd, run(seq, tmp_path / "o1", f"onnx:{big}"), str(big), "limit")
    assert time.perf_counter() - started < 5.0
