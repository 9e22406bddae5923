"""What a row says about its run (issue 36, point 1): the whole detector configuration with
a label per fault model, the seed and each suite knob, settings as numbers, and sequences
named relative to the sweep so that a copied sweep folder keeps every figure."""

from __future__ import annotations

import csv
import json
import shutil
import sqlite3
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main

pytestmark = pytest.mark.render

SUITE = (
    "suite: walkers\nbase: smoke\noverrides: {frames: 4}\ngrid:\n  actors.0.count: [1, 2]\nseeds: [1, 2]\n"
)


@pytest.fixture(scope="module")
def swept(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A sweep over a 4-sequence suite (2 walker counts x 2 seeds) with two fault models."""
    root = tmp_path_factory.mktemp("rows")
    (root / "walkers.yaml").write_text(SUITE)
    (root / "spec.yaml").write_text(
        "sweep: rows\nsuite: walkers.yaml\nstrategies: [none, box_rule, prior_flow]\n"
        "thresholds: {prior_flow: {k: {grid: [1.5, 3]}}}\n"
        "detectors:\n  - {detector: groundtruth, faults: {miss: 0.5}}\n"
        "  - {detector: groundtruth, faults: {latency: 3}}\n"
    )
    assert main(["sweep", str(root / "spec.yaml"), "-o", str(root / "sw")]) == 0
    return root


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open() as handle:
        return list(csv.DictReader(handle))


def test_two_fault_models_are_two_configurations(swept: Path):
    """The probe: `miss: 0.5` and `latency: 3` were both `groundtruth+faults`, and summary.json
    averaged them into one box_rule configuration over "4 sequences"."""
    rows = _csv(swept / "sw" / "results.csv")
    assert {r["detector"] for r in rows} == {"groundtruth+miss=0.5", "groundtruth+latency=3"}
    faults = {r["detector"]: json.loads(r["detector_config"])["faults"] for r in rows}
    assert faults["groundtruth+miss=0.5"]["miss"] == 0.5 and faults["groundtruth+latency=3"]["latency"] == 3
    summary = json.loads((swept / "sw" / "summary.json").read_text())
    box = [c for c in summary["configurations"] if c["strategy"] == "box_rule"]
    assert len(box) == 2 * 2 and all(c["sequences"] == 2 for c in box)  # 2 families x 2 fault models


def test_a_row_carries_its_seed_its_knobs_and_typed_settings(swept: Path):
    rows = _csv(swept / "sw" / "results.csv")
    assert {r["seed"] for r in rows} == {"1", "2"}
    assert {r["knob.actors.0.count"] for r in rows} == {"1", "2"}
    assert {r["setting.k"] for r in rows if r["strategy"] == "prior_flow"} == {"1.5", "3"}
    with sqlite3.connect(swept / "sw" / "results.sqlite") as db:
        kinds = {
            row[0]
            for row in db.execute("SELECT json_type(settings, '$.k') FROM runs WHERE strategy = 'prior_flow'")
        }
        knobs = {row[0] for row in db.execute("SELECT json_type(knobs, '$.\"actors.0.count\"') FROM runs")}
    assert kinds == {"real", "integer"} and knobs == {"integer"}  # numbers, not "1.5" and "3"


def test_a_copied_sweep_folder_keeps_every_figure(swept: Path, tmp_path: Path, capsys):
    """The probe: rows kept the absolute sequence path, and after copying the folder and
    resuming, rho was blank on 31 of 32 rows."""
    copy = tmp_path / "copied"
    shutil.copytree(swept / "sw", copy)
    shutil.rmtree(swept / "sw" / "sequences")  # the original's sequences are gone
    capsys.readouterr()
    assert main(["sweep", str(swept / "spec.yaml"), "-o", str(copy)]) == 0
    assert "(32 already done)" in capsys.readouterr().out
    rows = _csv(copy / "results.csv")
    assert all(not Path(r["sequence"]).is_absolute() for r in rows)
    base = {(r["sequence"], r["detector"]): r["ate_rmse_m"] for r in rows if r["strategy"] == "none"}
    scored = [
        r
        for r in rows
        if r["strategy"] != "none" and r["ate_rmse_m"] and base[(r["sequence"], r["detector"])]
    ]
    assert len(scored) > 10 and all(r["rho_percent"] != "" for r in scored)
