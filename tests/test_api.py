"""The Python API (``import depotbench``): the documented examples run as written, saved as
files, and each function gives what the command line gives for the same job, read back from
the files the command line writes (record.json, results.csv, its exit status) or from evo."""

from __future__ import annotations

import csv
import inspect
import itertools
import json
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.cli.main import main
from depotbench.eval.metrics.alignment import Alignment
from depotbench.eval.metrics.evaluate import ComparisonOptions
from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS, RunRecord
from depotbench.eval.metrics.trajectory import read_tum

import depotbench
from tests.evo_reference import evo_ape

ROOT = Path(__file__).resolve().parents[1]
API_PAGE = ROOT / "docs" / "api.md"
EXAMPLES = ROOT / "assets" / "examples"


def python_blocks(page: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S)


def run_saved(code: str, where: Path, name: str) -> subprocess.CompletedProcess:
    """A documented example as a user runs it: saved as a file, run by a fresh interpreter in
    ``where`` (not ``python -c``: a spawned worker imports a script again, never -c's code)."""
    script = where / name
    script.write_text(code, encoding="utf-8")
    return subprocess.run(
        [sys.executable, script.name],
        cwd=where,
        capture_output=True,
        text=True,
        env=os.environ | {"MUJOCO_GL": "egl"},
        timeout=600,
    )


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, str]:
    """The page's session example, saved as a file and run in an empty folder."""
    where = tmp_path_factory.mktemp("api")
    session_code, _tables = python_blocks(API_PAGE)
    done = run_saved(session_code, where, "session.py")
    assert done.returncode == 0, done.stderr[-3000:]
    return where / "work", done.stdout


def test_the_documented_example_runs_and_says_what_it_did(session):
    work, out = session
    # 20 frames asked; the analog's tum sensor loses about 3.5 % of them, as TUM's driver did.
    written = re.search(r"^(\d+) frames of walking_static$", out, flags=re.M)
    assert written and 17 <= int(written.group(1)) <= 20, out
    assert "gates passed" in out
    assert (work / "report" / "index.html").is_file()
    assert (work / "run-box_rule" / "record.json").is_file()
    # Each swept run printed once: 2 seeds x (none + prior_flow at 2 values), its settings typed.
    assert len(re.findall(r"^[12] (none|prior_flow) ", out, flags=re.M)) == 6
    assert len(re.findall(r"^[12] prior_flow \{'k': [23]\} ", out, flags=re.M)) == 4
    assert re.search(r"^best of .+: (none|prior_flow k=[23]), mean ATE \d\.\d{4} m$", out, flags=re.M)
    # The sweep's repr: a few lines (counts, the best per family), not its records.
    lines = out.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("SweepResult("))
    shown = list(itertools.takewhile(lambda line: not re.match(r"[12] ", line), lines[first:]))
    assert 2 <= len(shown) <= 3 and "6 runs (0 failed, 6 done now) over 2 sequences" in shown[0]
    assert shown[1].startswith("  best ") and shown[-1].endswith(")")


def test_a_run_is_the_record_the_command_line_writes(session, tmp_path: Path):
    work, _ = session
    sequence = work / "walking-7"
    record = depotbench.run(sequence, strategy="box_rule", settings={"box_dilation_px": 8})
    assert isinstance(record, RunRecord)
    cli_run = tmp_path / "cli-run"
    args = ["run", str(sequence), "-o", str(cli_run), "--strategy", "box_rule"]
    assert main([*args, "--set", "box_dilation_px=8"]) == 0
    written = json.loads((cli_run / "record.json").read_text())
    for name in DETERMINISTIC_FIELDS:
        assert getattr(record, name) == written[name], name
    # The example's own run folder (out=) holds the same record.
    stored = RunRecord.from_row(json.loads((work / "run-box_rule" / "record.json").read_text()))
    assert {n: getattr(stored, n) for n in DETERMINISTIC_FIELDS} == {
        n: getattr(record, n) for n in DETERMINISTIC_FIELDS
    }


def test_a_sweep_returns_the_rows_it_stored(session):
    work, _ = session
    result = depotbench.sweep(work / "sweep.yaml", work / "sweep", workers=1)
    assert result.written == 0  # resumed: every run is in the folder already
    with open(work / "sweep" / "results.csv", newline="") as f:
        stored = {row["key"]: row for row in csv.DictReader(f)}
    assert {r.key for r in result.records} == set(stored)
    for record in result.records:
        row = stored[record.key]
        assert float(row["ate_rmse_m"]) == pytest.approx(record.ate_rmse_m, rel=1e-12)
        assert row["strategy"] == record.strategy and row["settings"] == record.settings
        assert record.setting_values == json.loads(row["settings"])  # typed: k is 2, not "2"
        assert record.knob_values == json.loads(row["knobs"]) and record.knob_values["seed"] == record.seed
    summary = json.loads((work / "sweep" / "summary.json").read_text())
    assert result.summary.to_dict() == summary
    assert {family: c.to_dict() for family, c in result.best.items()} == summary["best"]
    (family, best), *_ = result.best.items()
    assert isinstance(best, depotbench.Configuration) and best.strategy in ("none", "prior_flow")
    assert best.stats["ate_rmse_m"].mean == pytest.approx(best["ate_rmse_m"])
    assert {c.settings.get("k") for c in result.summary.configurations} == {None, 2, 3}
    # The scored runs carry rho against the none run of their sequence, as results.csv does.
    assert [run.record for run in result.runs] == result.records
    for run in result.runs:
        shown = stored[run.key]["rho_percent"]
        if shown == "":
            assert run.rho_percent is None
        else:
            assert float(shown) == pytest.approx(run.rho_percent, rel=1e-9)
    assert all(run.rho_percent is not None for run in result.runs)  # every sequence has its none run


def test_check_agrees_with_the_command_lines_exit(session, tmp_path: Path):
    work, _ = session
    strict = (work / "gates.yaml").read_text().replace("lost_fraction: {max: 0.5}", "ate_rmse_m: {max: 1e-9}")
    gates = work / "strict-gates.yaml"
    gates.write_text(strict)
    verdict = depotbench.check(gates, work / "sweep")
    assert not verdict.passed
    assert len(verdict.failures) == 4 and all("ate_rmse_m" in line for line in verdict.failures)
    assert main(["check", str(gates), "-o", str(work / "sweep")]) == 1
    assert depotbench.check(work / "gates.yaml", work / "sweep").passed
    assert main(["check", str(work / "gates.yaml"), "-o", str(work / "sweep")]) == 0


def test_compare_pairs_a_folder_with_itself_as_no_change(session):
    work, _ = session
    found = depotbench.compare(work / "sweep", work / "sweep")
    (comparison,) = found.values()
    assert comparison.comparisons and not comparison.regressions(0.0)
    assert all(c.change.change in (0.0, None) for c in comparison.comparisons if c.figure == "ate_rmse_m")


def test_evaluate_is_evo():
    gt, est = EXAMPLES / "fr1_xyz_groundtruth.txt", EXAMPLES / "fr1_xyz_rgbdslam.txt"
    result = depotbench.evaluate(gt, est, ComparisonOptions(alignment=Alignment.SIM3))
    expected = evo_ape(read_tum(gt), read_tum(est), "sim3")
    assert result.pairs == 786
    assert result.ate.statistics.rmse == pytest.approx(expected["rmse"], rel=1e-6)


def test_changes_are_checked_as_the_schema_checks_them():
    spec = depotbench.scenario("walking_static", seed=3, frames=12, flow=True)
    assert (spec.seed, spec.frames, spec.flow) == (3, 12, True)  # flow: a field with no limits
    assert depotbench.scenario("default", frames=5).frames == 5


def test_bad_input_is_one_line_naming_the_field(tmp_path: Path):
    with pytest.raises(InputError, match=r"^seed -1: .*the scenario's seed\)$"):
        depotbench.scenario("walking_static", seed=-1)
    with pytest.raises(InputError, match="no library scenario named 'nowhere'"):
        depotbench.scenario("nowhere")
    with pytest.raises(InputError, match="colour: not a field of a scenario"):
        depotbench.scenario("walking_static", colour="red")
    with pytest.raises(InputError, match="unknown strategy 'fast'"):
        depotbench.run(tmp_path, strategy="fast")
    with pytest.raises(InputError, match="settings: unknown setting 'kk'"):
        depotbench.run(tmp_path, settings={"kk": 1})
    with pytest.raises(InputError, match="settings: setting n_features=800.5 must be a whole number"):
        depotbench.run(tmp_path, settings={"n_features": 800.5})
    with pytest.raises(InputError, match="detector"):
        depotbench.run(tmp_path, detector="yolo9000")
    with pytest.raises(InputError, match="compare needs two folders"):
        depotbench.compare(tmp_path)


def test_a_users_folder_is_never_generated_over(tmp_path: Path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(InputError):
        depotbench.generate("walking_static", mine, frames=2, overwrite=True)
    assert (mine / "notes.txt").read_text() == "keep"


def test_import_depotbench_loads_no_heavy_part():
    heavy = "('mujoco', 'cv2', 'onnxruntime', 'scipy')"
    code = f"import sys, depotbench; print(sorted(m for m in {heavy} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
    assert set(depotbench.__all__) >= {"generate", "run", "sweep", "check", "compare", "report", "evaluate"}


def test_json_on_the_command_line_is_what_the_files_and_the_api_hold(session, tmp_path: Path, capsys):
    """--json prints the result in the shape of the file the command writes: run's metrics.json,
    sweep's summary.json, check's verdicts (as the API's GateReport, and the exit status)."""
    work, _ = session
    out = tmp_path / "run"
    capsys.readouterr()
    assert main(["run", str(work / "walking-7"), "-o", str(out), "--strategy", "box_rule", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((out / "metrics.json").read_text())

    assert main(["sweep", str(work / "sweep.yaml"), "-o", str(work / "sweep"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads((work / "sweep" / "summary.json").read_text())

    strict = (work / "gates.yaml").read_text().replace("lost_fraction: {max: 0.5}", "ate_rmse_m: {max: 1e-9}")
    gates = work / "strict-gates-json.yaml"  # beside gates.yaml: its sequences are relative
    gates.write_text(strict)
    for path, code in ((work / "gates.yaml", 0), (gates, 1)):
        assert main(["check", str(path), "-o", str(work / "sweep"), "--json"]) == code
        verdict = json.loads(capsys.readouterr().out)
        expected = depotbench.check(path, work / "sweep")
        assert verdict["passed"] is expected.passed is (code == 0)
        assert verdict["failures"] == expected.failures
        assert len(verdict["results"]) == len(expected.results)
        for shown, result in zip(verdict["results"], expected.results, strict=True):
            assert [b["value"] for b in shown["budgets"]] == [v.value for v in result.verdicts]


def test_the_tables_example_runs_saved_after_the_session(session):
    """The page's second example (the [pandas] extra), saved and run where the session ran."""
    work, _ = session
    _session, tables = python_blocks(API_PAGE)
    done = run_saved(tables, work.parent, "tables.py")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "success_rate" in done.stdout and "significant" in done.stdout


def test_a_sweeps_table_is_results_csv_typed(session):
    """to_pandas() holds what results.csv holds (read by the csv module), column for column,
    with figures as floats and settings and knobs spread to columns as the CSV spreads them."""
    work, _ = session
    result = depotbench.sweep(work / "sweep.yaml", work / "sweep")
    frame = result.to_pandas()
    with open(work / "sweep" / "results.csv", newline="") as f:
        reader = csv.DictReader(f)
        stored, header = list(reader), reader.fieldnames
    assert list(frame.columns) == header
    assert len(frame) == len(stored) == 6
    for column in (
        "ate_rmse_m",
        "rejection_recall",
        "rho_percent",
        "tracked_fraction",
        "setting.k",
        "knob.seed",
    ):
        assert str(frame[column].dtype) == "float64", column
    assert str(frame["frames"].dtype) == "Int64" and str(frame["seed"].dtype) == "Int64"
    by_key = frame.set_index("key")
    for row in stored:
        ours = by_key.loc[row["key"]]
        for column, text in row.items():
            if column == "key":
                continue  # the index
            value = ours[column]
            if text == "":
                assert value is None or value != value, column  # NaN or None
            elif str(frame[column].dtype) in ("float64", "Int64"):
                assert float(value) == pytest.approx(float(text), rel=1e-12), column
            elif column not in ("sequence",):  # the CSV names the sequence inside the sweep folder
                assert str(value) == text, column
    assert set(frame.loc[frame["strategy"] == "prior_flow", "setting.k"]) == {2.0, 3.0}
    assert frame.loc[frame["strategy"] == "none", "setting.k"].isna().all()

    configurations = result.summary.to_pandas()
    assert len(configurations) == len(result.summary.configurations) == 3
    assert (
        str(configurations["ate_rmse_m"].dtype) == "float64" and str(configurations["runs"].dtype) == "Int64"
    )
    mean = frame[frame["strategy"] == "none"]["ate_rmse_m"].mean()
    assert configurations.set_index("strategy").loc["none", "ate_rmse_m"] == pytest.approx(mean)


def test_a_comparisons_table_is_what_compare_json_prints(session, capsys):
    work, _ = session
    found = depotbench.compare(work / "sweep", work / "sweep")
    assert isinstance(found, depotbench.Comparisons) and list(found) == [work / "sweep"]
    frame = found.to_pandas()
    capsys.readouterr()
    assert main(["compare", str(work / "sweep"), str(work / "sweep"), "--json"]) == 0
    (printed,) = json.loads(capsys.readouterr().out).values()
    assert len(frame) == len(printed["comparisons"]) > 0
    for (_, ours), theirs in zip(frame.iterrows(), printed["comparisons"], strict=True):
        assert ours["folder"] == str(work / "sweep")
        for name, value in theirs.items():
            if value is None:
                assert ours[name] != ours[name], name  # NaN
            else:
                assert ours[name] == value, name
    assert str(frame["change"].dtype) == "float64" and str(frame["pairs"].dtype) == "Int64"
    assert repr(found).count("\n") == 1 and "0 significant" in repr(found)


def test_to_pandas_without_pandas_names_the_extra(session, monkeypatch):
    work, _ = session
    result = depotbench.sweep(work / "sweep.yaml", work / "sweep")
    monkeypatch.setitem(sys.modules, "pandas", None)  # import pandas raises ImportError
    with pytest.raises(ImportError) as raised:
        result.to_pandas()
    assert isinstance(raised.value, depotbench.MissingExtra)
    assert str(raised.value) == "to_pandas needs pandas: pip install 'depotbench[pandas]'"
    with pytest.raises(depotbench.MissingExtra):
        depotbench.compare(work / "sweep", work / "sweep").to_pandas()


def test_every_public_signature_resolves():
    """typing.get_type_hints on each public function and class of ``import depotbench`` (it
    raised NameError for types named only under TYPE_CHECKING), and on their methods but
    to_pandas, whose DataFrame would import pandas for every user of the API."""
    for name in depotbench.__all__:
        value = getattr(depotbench, name)
        if not callable(value):
            continue
        hints = typing.get_type_hints(value)
        if inspect.isfunction(value):
            assert "return" in hints, name
            assert set(inspect.signature(value).parameters) <= set(hints), name
        if inspect.isclass(value):
            for method_name, method in vars(value).items():
                if inspect.isfunction(method) and method_name != "to_pandas":
                    typing.get_type_hints(method)
    assert typing.get_type_hints(depotbench.run)["return"] is RunRecord
    assert typing.get_type_hints(depotbench.sweep)["return"] is depotbench.SweepResult
    assert (ROOT / "depotbench" / "py.typed").is_file()


GUARDLESS = """import depotbench

depotbench.sweep("sweep.yaml", "out", workers=2)
"""


def test_workers_from_a_scripts_top_level_are_refused_in_one_line(tmp_path: Path):
    """A script starting workers outside ``if __name__ == "__main__":`` would run again in each
    spawned worker (FileExistsError, then BrokenProcessPool): refused before anything is
    written, naming the line. Under the guard the same call goes on (and finds no spec)."""
    done = run_saved(GUARDLESS, tmp_path, "unguarded.py")
    assert done.returncode == 1
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("depotbench.core.errors.InputError: workers=2: unguarded.py, line 3: ")
    assert 'if __name__ == "__main__":' in last
    assert not (tmp_path / "out").exists()

    guarded = "import depotbench\n\nif __name__ == '__main__':\n    " + GUARDLESS.splitlines()[-1] + "\n"
    done = run_saved(guarded, tmp_path, "guarded.py")
    assert done.returncode == 1 and "sweep.yaml" in done.stderr.strip().splitlines()[-1]
    assert "__main__" not in done.stderr.strip().splitlines()[-1]
    # Called through a function from the top level: the top-level line is named. One worker
    # starts no process: nothing to say.
    called = "import depotbench\n\ndef go():\n    depotbench.sweep('sweep.yaml', 'out', workers=2)\n\n"
    done = run_saved(called + "go()\n", tmp_path, "called.py")
    assert "line 6: " in done.stderr.strip().splitlines()[-1]
    done = run_saved(GUARDLESS.replace("workers=2", "workers=1"), tmp_path, "one.py")
    assert "__main__" not in done.stderr.strip().splitlines()[-1]


@pytest.mark.slow
def test_the_readmes_example_runs_saved(tmp_path: Path):
    """README's "From Python" example as written (60 frames rendered and tracked twice)."""
    (code,) = [block for block in python_blocks(ROOT / "README.md") if "depotbench.generate(" in block]
    done = run_saved(code, tmp_path, "readme.py")
    assert done.returncode == 0, done.stderr[-3000:]
    bare, boxed, recall = (float(x) for x in done.stdout.split())
    assert bare > 0 and boxed > 0 and 0 <= recall <= 1
