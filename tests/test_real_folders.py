"""A run on a real TUM folder picks a detector that needs nothing the folder lacks (probe U4).

A real folder (no meta.json, no gt/) has no ground truth to draw boxes from, and ``run``
defaulted to the ground-truth detector: ``depotbench run REALDIR -o out`` stopped with "the
groundtruth detector needs a generated sequence" even with ``--strategy none``, which uses
no boxes.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from depotbench.detectors.config import DetectorKind
from depotbench.eval.cli.main import main
from depotbench.eval.run.harness import default_detector

from tests.sequences import write_sequence


@pytest.fixture
def real_folder(tmp_path: Path) -> Path:
    """Four frames as a recording would have them: images, lists, ground truth, a camera."""
    root = tmp_path / "recording"
    write_sequence(root, n=4)
    (root / "meta.json").unlink()
    shutil.rmtree(root / "gt")
    return root


def test_a_run_on_a_real_folder_without_a_detector_named_uses_none(real_folder: Path, tmp_path: Path):
    assert main(["run", str(real_folder), "-o", str(tmp_path / "out")]) == 0
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["detector"] == "none" and metrics["frames"] == 4


def test_a_strategy_that_needs_boxes_on_a_real_folder_names_the_detector_to_give(
    real_folder: Path, tmp_path: Path, capsys
):
    out = tmp_path / "out"
    assert main(["run", str(real_folder), "--strategy", "box_rule", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--strategy box_rule needs boxes" in err[0] and "--detector onnx" in err[0]
    assert not out.exists()


def test_a_generated_sequence_keeps_the_true_boxes(tmp_path: Path):
    write_sequence(tmp_path / "generated", n=2)
    assert default_detector(tmp_path / "generated", "box_rule").kind is DetectorKind.GROUNDTRUTH
    assert default_detector(tmp_path / "generated", "none").kind is DetectorKind.GROUNDTRUTH
