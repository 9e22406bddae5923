"""``baseline:`` in a sweep spec: rho against a chosen configuration instead of each run's
own ``none``, and unchanged against ``none`` where no baseline is named; checked against
rho computed here from the rows' ATE (Yu et al. 2018's (mu - gamma) / mu)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main


@pytest.fixture(scope="module")
def sequences(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    root = tmp_path_factory.mktemp("smoke")
    for seed in (1, 2):
        assert (
            main(["generate", "smoke", "-o", str(root / f"s{seed}"), "--seed", str(seed), "--frames", "20"])
            == 0
        )
    return [root / "s1", root / "s2"]


def _sweep(tmp_path: Path, sequences: list[Path], name: str, baseline: str = "") -> list[dict[str, str]]:
    spec = tmp_path / f"{name}.yaml"
    spec.write_text(
        f"sweep: {name}\nsequences: [{', '.join(map(str, sequences))}]\n"
        "strategies: [none, box_rule, prior_flow]\n"
        "thresholds: {prior_flow: {k: {grid: [2.0, 3.0]}}}\n" + baseline
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / name), "--workers", "1"]) == 0
    with (tmp_path / name / "results.csv").open() as f:
        return list(csv.DictReader(f))


def _rho(base: float, value: float) -> float:
    return (base - value) / base * 100.0


def test_a_named_baseline_gives_every_rho_and_none_stays_the_default(sequences: list[Path], tmp_path: Path):
    default = _sweep(tmp_path, sequences, "default")
    chosen = _sweep(tmp_path, sequences, "chosen", "baseline: {strategy: box_rule}\n")
    for rows, strategy in ((default, "none"), (chosen, "box_rule")):
        assert len(rows) == 2 * 4
        base = {r["sequence_fingerprint"]: float(r["ate_rmse_m"]) for r in rows if r["strategy"] == strategy}
        assert len(base) == 2
        for r in rows:
            expected = _rho(base[r["sequence_fingerprint"]], float(r["ate_rmse_m"]))
            assert float(r["rho_percent"]) == pytest.approx(expected, abs=1e-9), (strategy, r["strategy"])
    # the same runs: only the baseline moved
    ate = {(r["sequence_fingerprint"], r["strategy"], r["settings"]): r["ate_rmse_m"] for r in default}
    assert ate == {(r["sequence_fingerprint"], r["strategy"], r["settings"]): r["ate_rmse_m"] for r in chosen}
    summary = json.loads((tmp_path / "chosen" / "summary.json").read_text())
    assert summary["baseline"]["strategy"] == "box_rule"
    assert json.loads((tmp_path / "default" / "summary.json").read_text())["baseline"] is None


def test_a_baseline_that_picks_two_runs_of_a_sequence_is_one_line(
    sequences: list[Path], tmp_path: Path, capsys
):
    spec = tmp_path / "two.yaml"
    spec.write_text(
        f"sweep: two\nsequences: [{sequences[0]}]\nstrategies: [none, prior_flow]\n"
        "thresholds: {prior_flow: {k: {grid: [2.0, 3.0]}}}\nbaseline: {strategy: prior_flow}\n"
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "two"), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "baseline (strategy prior_flow): two runs on" in err[0] and "settings" in err[0]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("baseline: {}\n", "name the baseline's"),
        ("baseline: {tracker: orbslam3}\n", "baseline.tracker 'orbslam3' is not a tracker of this sweep"),
        ("baseline: {strategy: mask}\n", "baseline.strategy 'mask' is not among the strategies"),
    ],
)
def test_a_baseline_the_sweep_cannot_have_is_refused_before_it_runs(
    tmp_path: Path, capsys, text: str, message: str
):
    spec = tmp_path / "bad.yaml"
    spec.write_text("sweep: bad\nsequences: [x]\nstrategies: [none, box_rule]\n" + text)
    assert main(["sweep", str(spec), "-o", str(tmp_path / "bad")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
