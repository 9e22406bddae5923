"""Sweeps: spec expansion and validation, the SQLite store, resuming, and SIGKILL safety."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS
from depotbench.eval.sweep.spec import SweepSpec, load_sweep, variants
from depotbench.eval.sweep.store import ResultStore
from depotbench.scenes.schema import SpecError

from tests.records import record
from tests.sequences import write_sequence

REPO = Path(__file__).resolve().parents[1]


def _spec(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "sweep.yaml"
    path.write_text(text)
    return path


def test_thresholds_expand_into_grids_ranges_and_seeded_draws(tmp_path: Path):
    spec = load_sweep(
        _spec(
            tmp_path,
            "sweep: s\nsequences: [x]\nstrategies: [none, prior_flow, box_epipolar_flow]\n"
            "thresholds:\n"
            "  prior_flow: {k: {random: {low: 1.0, high: 4.0, samples: 3, seed: 7}}}\n"
            "  box_epipolar_flow:\n"
            "    epsilon_px: {grid: [0.5, 2]}\n"
            "    l_thr1_px: {range: [0.5, 1.5, 0.5]}\n",
        )
    )
    found = variants(spec)
    assert found[0].strategy == "none" and found[0].settings == ()
    draws = np.random.default_rng(7).uniform(1.0, 4.0, 3)
    assert [dict(v.settings)["k"] for v in found if v.strategy == "prior_flow"] == [float(d) for d in draws]
    epipolar = [dict(v.settings) for v in found if v.strategy == "box_epipolar_flow"]
    assert epipolar == [
        {"epsilon_px": e, "l_thr1_px": t} for e in (0.5, 2.0) for t in (0.5, 1.0, 1.5)
    ]  # values typed as their fields: the text of a value is parsed once, where it came in
    assert all(type(v) is float for variant in found for _, v in variant.settings)
    assert variants(spec) == found  # seeded


def test_one_threshold_value_is_one_job_however_it_was_written(tmp_path: Path):
    """``--set k=2.0`` and a spec's ``grid: [2]`` are one configuration: one job key (the CLI's
    text and the spec's number were two different texts, so the same run was keyed twice)."""
    from depotbench.detectors.config import DetectorConfig
    from depotbench.eval.run.harness import job_key
    from depotbench.slam.config import parse_setting

    spec = load_sweep(
        _spec(
            tmp_path,
            "sweep: s\nsequences: [x]\nstrategies: [prior_flow, box_rule]\n"
            "thresholds: {prior_flow: {k: {grid: [2]}}, box_rule: {box_dilation_px: {grid: [8]}}}\n",
        )
    )
    found = {v.strategy: v.settings for v in variants(spec)}

    def key(settings) -> str:
        return job_key("fingerprint", (("kind", "builtin"),), DetectorConfig(), "prior_flow", settings)

    for text in ("2", "2.0", "2.00"):
        assert key((("k", parse_setting("k", text)),)) == key(found["prior_flow"])
    assert key((("box_dilation_px", parse_setting("box_dilation_px", "8")),)) == key(found["box_rule"])


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("sweep: s\nstrategies: [none]\n", "give a suite or sequences"),
        ("sweep: s\nsequences: [x]\nstrategies: [magic]\n", "unknown strategy 'magic'"),
        (
            "sweep: s\nsequences: [x]\nthresholds: {prior_flow: {k: {grid: [2]}}}\n",
            "not among the strategies",
        ),
        (
            "sweep: s\nsequences: [x]\nstrategies: [prior_flow]\n"
            "thresholds: {prior_flow: {k: {range: [3, 1, 1]}}}\n",
            "start <= stop",
        ),
        (
            "sweep: s\nsequences: [x]\nstrategies: [prior_flow]\nthresholds: {prior_flow: {k: {grid: []}}}\n",
            "at least 1",
        ),
        ("sweep: 's/../x'\nsequences: [x]\n", "sweep"),
        ("sweep: s\nsequences: [x]\nfrobnicate: 1\n", "frobnicate"),
    ],
)
def test_bad_sweep_specs_are_refused_with_the_field(tmp_path: Path, text: str, needle: str):
    with pytest.raises(SpecError, match=None) as info:
        load_sweep(_spec(tmp_path, text))
    assert needle in str(info.value) and "sweep.yaml" in str(info.value)


def test_thresholds_are_checked_against_the_slam_configuration_before_anything_runs(tmp_path: Path, capsys):
    write_sequence(tmp_path / "a", n=3, with_flow=False)
    spec = _spec(
        tmp_path,
        f"sweep: s\nsequences: [{tmp_path / 'a'}]\nstrategies: [prior_flow]\n"
        "thresholds: {prior_flow: {kk: {grid: [2]}}}\n",
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "out"), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "thresholds.prior_flow.kk: unknown setting (known: " in err and "--set" not in err
    assert not (tmp_path / "out" / "results.sqlite").exists()


SWEEP = """\
sweep: kill
sequences: [{a}, {b}]
detectors: [groundtruth, {{detector: groundtruth, faults: {{miss: 0.5}}}}]
strategies: [none, box_rule, prior_flow, box_epipolar_flow]
thresholds:
  prior_flow: {{k: {{grid: [1.5, 2.5, 3.5]}}}}
  box_epipolar_flow: {{epsilon_px: {{grid: [0.5, 1.0]}}}}
"""
"""2 sequences x 2 detectors x (none, box_rule, 3 k, 2 epsilon) = 28 runs."""


def _sweep_setup(tmp_path: Path) -> Path:
    for name, seed in (("a", 0), ("b", 1)):
        write_sequence(tmp_path / name, n=12, seed=seed, with_flow=False)
    return _spec(tmp_path, SWEEP.format(a=tmp_path / "a", b=tmp_path / "b"))


def _table(out: Path) -> list[dict]:
    with ResultStore(out / "results.sqlite") as store:
        return [{k: r[k] for k in DETERMINISTIC_FIELDS} for r in store.rows()]


def _command(spec: Path, out: Path) -> list[str]:
    return [
        sys.executable,
        "-m",
        "depotbench.eval.cli.main",
        "sweep",
        str(spec),
        "-o",
        str(out),
        "--workers",
        "2",
    ]


@pytest.mark.slow  # 60 s; test_kill.py kills a run at random moments in the default run
def test_a_sweep_killed_at_random_moments_and_resumed_equals_an_uninterrupted_one(tmp_path: Path):
    spec = _sweep_setup(tmp_path)
    env = {**os.environ, "DEPOTBENCH_CACHE": "off"}
    whole = subprocess.run(
        _command(spec, tmp_path / "whole"), cwd=REPO, env=env, capture_output=True, text=True
    )
    assert whole.returncode == 0, whole.stderr
    reference = _table(tmp_path / "whole")
    assert len(reference) == 28
    rng = np.random.default_rng(2026)
    counts = []
    for moment in rng.uniform(1.5, 6.0, 5):
        proc = subprocess.Popen(
            _command(spec, tmp_path / "killed"),
            cwd=REPO,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        time.sleep(moment)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        database = tmp_path / "killed" / "results.sqlite"
        counts.append(len(_table(tmp_path / "killed")) if database.exists() else 0)
    print(f"rows after each of 5 SIGKILLs: {counts}")
    resumed = subprocess.run(
        _command(spec, tmp_path / "killed"), cwd=REPO, env=env, capture_output=True, text=True
    )
    assert resumed.returncode == 0, resumed.stderr
    assert _table(tmp_path / "killed") == reference  # row for row
    assert counts == sorted(counts)  # no finished row was ever lost
    # Every row is whole: SQLite's own check, and no NULL key.
    with sqlite3.connect(tmp_path / "killed" / "results.sqlite") as db:
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"


def test_rerunning_a_finished_sweep_runs_nothing_and_exports_rho(tmp_path: Path, capsys):
    spec = _sweep_setup(tmp_path)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "-o", str(out), "--workers", "1"]) == 0
    assert "wrote 28 rows" in capsys.readouterr().out
    assert main(["sweep", str(spec), "-o", str(out), "--workers", "1"]) == 0
    assert "wrote 0 rows" in capsys.readouterr().out
    header, *lines = (out / "results.csv").read_text().splitlines()
    assert len(lines) == 28 and "rho_percent" in header.split(",")
    assert {line.split(",")[1] for line in lines} == {"test"}  # the sequences' scenario family
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["configurations"]) == 14  # 2 detectors x 7 variants, averaged over 2 sequences


def _config(family: str, strategy: str, ate: float, ms: float, k: str = "2") -> dict:
    return {
        "family": family,
        "tracker": "builtin",
        "detector": "groundtruth",
        "strategy": strategy,
        "settings": {"k": k},
        "ate_rmse_m": ate,
        "track_ms_median": ms,
        "rho_percent": None,
        "rejection_precision": None,
        "rejection_recall": None,
    }


def test_best_and_pareto_on_a_closed_case():
    from depotbench.eval.sweep.summary import best_per_family, pareto

    configs = [
        _config("a", "x", 0.010, 30.0, "1"),  # fastest
        _config("a", "x", 0.005, 35.0, "2"),  # best ATE
        _config("a", "x", 0.008, 40.0, "3"),  # dominated by the one above
        _config("a", "x", 0.005, 36.0, "4"),  # as accurate, slower: dominated
        _config("b", "y", 0.100, 20.0),
    ]
    assert best_per_family(configs)["a"]["settings"] == {"k": "2"}
    assert best_per_family(configs)["b"]["strategy"] == "y"
    front = pareto(configs)
    assert [(c["family"], c["settings"]["k"]) for c in front] == [("a", "2"), ("a", "1"), ("b", "2")]


def test_rho_is_taken_against_the_none_run_of_the_same_sequence_and_detector():
    from depotbench.eval.sweep.summary import with_rho

    rows = [
        record(sequence="s", detector="d", strategy="none", ate_rmse_m=0.4),
        record(sequence="s", detector="d", strategy="x", ate_rmse_m=0.1),
        record(sequence="s", detector="e", strategy="x", ate_rmse_m=0.1),
    ]
    assert [r["rho_percent"] for r in with_rho(rows)] == [0.0, pytest.approx(75.0), None]


def test_the_sweep_folder_is_not_somebody_elses(tmp_path: Path, capsys):
    spec = _sweep_setup(tmp_path)
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "notes.txt").write_text("mine")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "theirs"), "--workers", "1"]) == 2
    assert "not written by depotbench" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "theirs").iterdir()) == ["notes.txt"]


def test_spec_model_defaults():
    spec = SweepSpec(sweep="s", sequences=["x"])
    assert spec.trackers == ["builtin"] and spec.detectors == ["groundtruth"] and spec.strategies == ["none"]


@pytest.mark.slow  # 34 s (Ray starts a local cluster); the default run is near its 10-minute budget
def test_ray_and_local_backends_give_identical_rows(tmp_path: Path):
    """A local Ray instance, started by the test (extra [ray])."""
    pytest.importorskip("ray")
    from depotbench.eval.sweep.engine import expand, run_jobs

    spec = _sweep_setup(tmp_path)
    jobs = expand(load_sweep(spec), spec, [(tmp_path / "a", "test"), (tmp_path / "b", "test")])
    tables = {}
    for backend in ("local", "ray"):
        with ResultStore(tmp_path / f"{backend}.sqlite") as store:
            run_jobs(jobs, store, workers=2, progress=False, backend=backend)
        tables[backend] = _table_of(tmp_path / f"{backend}.sqlite")
    assert len(tables["local"]) == 28 and tables["ray"] == tables["local"]


def _table_of(database: Path) -> list[dict]:
    with ResultStore(database) as store:
        return [{k: r[k] for k in DETERMINISTIC_FIELDS} for r in store.rows()]


@pytest.mark.render
@pytest.mark.slow  # 23 s, as above
def test_ray_and_local_generate_a_suite_byte_for_byte(tmp_path: Path):
    pytest.importorskip("ray")
    from depotbench.scenes.generation import run_suite
    from depotbench.scenes.suite import load_suite

    suite = tmp_path / "s.yaml"
    suite.write_text("suite: s\nbase: smoke\noverrides: {frames: 4}\nseeds: [1, 2]\n")
    trees = {}
    for backend in ("local", "ray"):
        run_suite(load_suite(suite), suite, tmp_path / backend, workers=2, progress=False, backend=backend)
        root = tmp_path / backend
        trees[backend] = {
            str(p.relative_to(root)): p.read_bytes()
            for p in sorted(root.rglob("*"))
            if p.is_file() and "lock" not in p.name
        }
    assert len(trees["local"]) > 20 and trees["ray"] == trees["local"]


def _search_spec(tmp_path: Path, space: str, trials: int = 2, objective: str = "mean_ate") -> Path:
    if not (tmp_path / "a").exists():
        write_sequence(tmp_path / "a", n=6, with_flow=False)
    return _spec(
        tmp_path,
        f"sweep: s\nsequences: [{tmp_path / 'a'}]\nstrategies: [none]\n"
        f"search:\n  strategy: prior_flow\n  trials: {trials}\n  objective: {objective}\n  space:\n{space}",
    )


def _summary_search(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())["search"]


@pytest.mark.slow  # 25 s of Optuna studies
def test_a_search_whose_space_or_objective_changed_starts_a_study_of_its_own(tmp_path: Path, capsys):
    """Probe D3: the study resumed by the sweep's name; after k in [1, 4] became [5, 6] the
    report's best was k = 2.6, outside the space asked for."""
    pytest.importorskip("optuna")
    out = tmp_path / "out"
    assert main(["sweep", str(_search_spec(tmp_path, "    k: {low: 1.0, high: 4.0}\n")), "-o", str(out)]) == 0
    spec = _search_spec(tmp_path, "    k: {low: 5.0, high: 6.0}\n", trials=3)
    assert main(["sweep", str(spec), "-o", str(out)]) == 0
    search = _summary_search(out)
    assert search["trials"] == 3 and 5.0 <= float(search["settings"]["k"]) <= 6.0
    spec = _search_spec(tmp_path, "    k: {low: 5.0, high: 6.0}\n", trials=3, objective="ate_time")
    assert main(["sweep", str(spec), "-o", str(out)]) == 0
    assert _summary_search(out)["trials"] == 3 and _summary_search(out)["objective"] == "ate_time"


@pytest.mark.parametrize(
    "damage", ["truncated", pytest.param("not sqlite", marks=pytest.mark.slow)]
)  # 22 s each
def test_a_damaged_study_is_one_line_naming_it(tmp_path: Path, capsys, damage: str):
    """Probe C9: an 84-line SQLAlchemy traceback for a truncated optuna.sqlite."""
    pytest.importorskip("optuna")
    spec, out = _search_spec(tmp_path, "    k: {low: 1.0, high: 4.0}\n"), tmp_path / "out"
    assert main(["sweep", str(spec), "-o", str(out)]) == 0
    study = out / "optuna.sqlite"
    if damage == "truncated":
        study.write_bytes(study.read_bytes()[:3000])
    else:
        study.write_text("my notes\n")
    before = study.read_bytes()
    capsys.readouterr()
    assert main(["sweep", str(spec), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "optuna.sqlite: not a" in err, err
    if damage == "not sqlite":
        assert study.read_bytes() == before


@pytest.mark.parametrize(
    ("space", "needle"),
    [
        ("    k: {low: -5.0, high: -1.0}\n", "search.space.k: k = -5.0 is out of range"),
        ("    kk: {low: 1.0, high: 2.0}\n", "search.space.kk: unknown setting 'kk'"),
    ],
)
def test_a_bad_search_space_is_refused_by_its_field_before_any_output(
    tmp_path: Path, capsys, space: str, needle: str
):
    """Probe M4: the folder, both databases and the baseline run were made first, and the
    error named `thresholds.prior_flow: --set: …`."""
    assert main(["sweep", str(_search_spec(tmp_path, space)), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "out").exists()


def test_a_grid_too_large_to_list_is_refused_before_it_is_built(tmp_path: Path, capsys, monkeypatch):
    """Probe C12: three axes within their limits made 10^9 variants, built in memory until
    a MemoryError after 43 s."""

    def listed(spec):
        raise AssertionError("the grid was listed before it was counted")

    monkeypatch.setattr("depotbench.eval.sweep.engine.variants", listed)
    write_sequence(tmp_path / "a", n=3, with_flow=False)
    axis = "{range: [0.01, 10.0, 0.01]}"
    spec = _spec(
        tmp_path,
        f"sweep: h\nsequences: [{tmp_path / 'a'}]\nstrategies: [none, box_epipolar_flow]\n"
        f"thresholds:\n  box_epipolar_flow:\n    epsilon_px: {axis}\n    l_thr1_px: {axis}\n"
        f"    l_thr2_px: {axis}\n",
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "1000000001 jobs per sequence exceed the limit of 100000" in err and err.count("\n") == 1


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        ("strategies: [none]\nthresholds: {none: {k: {grid: [2]}}}\n", "the baseline takes no thresholds"),
        ("trackers: [orbslam3]\nstrategies: [box_rule]\n", "strategies: box_rule needs the built-in tracker"),
    ],
)
def test_a_spec_part_that_would_be_skipped_silently_is_refused(
    tmp_path: Path, capsys, body: str, needle: str
):
    write_sequence(tmp_path / "a", n=3, with_flow=False)
    spec = _spec(tmp_path, f"sweep: s\nsequences: [{tmp_path / 'a'}]\n{body}")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


def test_model_and_class_files_in_a_spec_are_found_beside_the_spec(tmp_path: Path, capsys):
    """Probe M5: `onnx:../models/m.onnx` was looked up from the working directory, after the
    output folder had been made, and the error named no field."""
    from depotbench.detectors.config import SHIPPED_MODEL

    write_sequence(tmp_path / "seq", n=2, with_flow=False)
    (tmp_path / "models").mkdir()
    (tmp_path / "specs").mkdir()
    spec = tmp_path / "specs" / "o.yaml"
    spec.write_text(
        'sweep: o\nsequences: [../seq]\nstrategies: [none]\ndetectors: ["onnx:../models/m.onnx"]\n'
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 2
    err = capsys.readouterr().err
    assert "o.yaml: detectors.0:" in err and str(tmp_path / "specs" / ".." / "models" / "m.onnx") in err, err
    assert not (tmp_path / "sw").exists()
    import shutil

    shutil.copyfile(SHIPPED_MODEL, tmp_path / "models" / "m.onnx")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
