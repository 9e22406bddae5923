"""The pytest plugin's reliability: relative --depotbench-dir, processes sharing it, and
configurations refused before any work (each test runs the plugin in a child session)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

# Imported here, before any pytester fixture: pytester drops the modules a test imported when
# it ends, and numpy's C core cannot be loaded twice in one process.
import depotbench.eval.sweep.execute  # noqa: F401
import depotbench.eval.trackers.vocabulary
import depotbench.scenes.generation  # noqa: F401
import depotbench.sim.generate
import pytest
from depotbench.core.errors import InputError

FAST_S = 5.0
"""A refused configuration returns within this: the refusal comes before generation
(about 2 s for 3 smoke frames) and before an ORB vocabulary build (about 4 min)."""


@pytest.mark.slow  # 11 s
@pytest.mark.render
def test_a_relative_depotbench_dir_is_resolved_once_against_where_pytest_started(pytester):
    """C16: a relative --depotbench-dir reached the sweep as a relative ``sequences:`` entry,
    resolved against runs/HASH/ (the spec's folder): every run failed."""
    pytester.makepyfile(
        """
        def test_first(depotbench_run):
            assert depotbench_run("smoke", strategy="box_rule", frames=3)["strategy"] == "box_rule"

        def test_after_a_chdir(depotbench_run, tmp_path, monkeypatch):
            monkeypatch.chdir(tmp_path)
            assert depotbench_run("smoke", strategy="box_rule", frames=3)["strategy"] == "box_rule"
        """
    )
    result = pytester.runpytest_subprocess(
        "--depotbench-dir=bench", "--depotbench-workers=1", "-p", "no:cacheprovider"
    )
    result.assert_outcomes(passed=2)
    # The test that changed directory used the same sequence, under the same folder.
    assert len(list((pytester.path / "bench" / "sequences").glob("smoke-*"))) == 1


CONFTEST = """
import os
import time
from pathlib import Path

import pytest

import depotbench.sim.generate

_build_world = depotbench.sim.generate.build_world


def _slow_build_world(scenario):
    # The writer holds the sequence's output lock from here: 2 s more, so the other
    # process (released by the same barrier within milliseconds) surely arrives meanwhile.
    time.sleep(2.0)
    return _build_world(scenario)


depotbench.sim.generate.build_world = _slow_build_world


@pytest.fixture
def meet():
    \"\"\"A barrier of the two processes: each waits here until the other has arrived.\"\"\"

    def wait(name):
        (Path({barrier!r}) / f"{{name}}-{{os.getpid()}}").touch()
        deadline = time.monotonic() + 120
        while len(list(Path({barrier!r}).glob(f"{{name}}-*"))) < 2:
            if time.monotonic() > deadline:
                pytest.fail(f"the other process never reached {{name}}")
            time.sleep(0.01)

    return wait
"""

SAME_RUN = """
def test_same_run_then_same_gates(meet, depotbench_run, depotbench_gates):
    meet("run")
    assert depotbench_run("smoke", strategy="box_rule", frames=3, seed=7)["strategy"] == "box_rule"
    meet("gates")
    assert depotbench_gates("gates.yaml").passed
"""

GATES = """
gates: shared
run: {suite: suite.yaml, strategies: [none, box_rule]}
checks: [{name: runs, strategies: [box_rule], budgets: {lost_fraction: {max: 1.0}}}]
"""


@pytest.mark.slow  # 30 s of two pytest sessions
@pytest.mark.render
def test_two_processes_sharing_the_dir_ask_for_the_same_sequence_run_and_gates_at_once(pytester):
    """C17: pytest-xdist workers sharing --depotbench-dir both saw a sequence missing and
    generated it; the second hit its lock ("another depotbench is writing it"). Here two
    sessions meet at a barrier before each request, so the overlap happens every time."""
    barrier = pytester.mkdir("barrier")
    pytester.makeconftest(CONFTEST.format(barrier=str(barrier)))
    pytester.makepyfile(test_same=SAME_RUN)
    (pytester.path / "suite.yaml").write_text("suite: tiny\nbase: smoke\noverrides: {frames: 3}\n")
    (pytester.path / "gates.yaml").write_text(GATES)
    command = [
        sys.executable,
        "-m",
        "pytest",
        "-p",
        "no:cacheprovider",
        f"--depotbench-dir={pytester.path / 'bench'}",
        "--depotbench-workers=1",
        "test_same.py",
    ]
    children = [
        subprocess.Popen(
            command, cwd=pytester.path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        for _ in range(2)
    ]
    outputs = [child.communicate(timeout=300)[0] for child in children]
    for child, output in zip(children, outputs, strict=True):
        assert child.returncode == 0, output
    assert len(list((pytester.path / "bench" / "sequences").glob("smoke-*"))) == 1


def _refused(pytester, monkeypatch, call: str) -> pytest.RunResult:
    """Run ``call`` in a child session that fails if anything is generated or a vocabulary
    is built, and that expects one InputError line within FAST_S seconds."""

    def tripwire(*args, **kwargs):
        raise AssertionError("depotbench_run did work before refusing the configuration")

    monkeypatch.setattr(depotbench.sim.generate, "generate", tripwire)
    monkeypatch.setattr(depotbench.eval.trackers.vocabulary, "default_vocabulary", tripwire)
    pytester.makepyfile(
        textwrap.dedent(
            f"""
            import time

            import pytest

            from depotbench.core.errors import InputError

            def test_refused(depotbench_run):
                started = time.monotonic()
                with pytest.raises(InputError) as caught:
                    {call}
                assert time.monotonic() - started < {FAST_S}
                assert "\\n" not in str(caught.value)
                print("REFUSED:", caught.value)
            """
        )
    )
    result = pytester.runpytest_inprocess(
        "--depotbench-workers=1",
        "-p",
        "no:cacheprovider",
        "-s",
        "-W",
        "ignore::pytest.PytestAssertRewriteWarning",
    )
    result.assert_outcomes(passed=1)
    return result


def test_a_strategy_the_tracker_cannot_run_is_refused_before_any_work(pytester, monkeypatch):
    """C18: orbslam3 with box_rule built the ORB vocabulary (about 4 min) for the none run,
    skipped the box_rule job silently and failed with IndexError."""
    result = _refused(
        pytester, monkeypatch, 'depotbench_run("smoke", strategy="box_rule", frames=3, tracker="orbslam3")'
    )
    result.stdout.fnmatch_lines(
        ["*REFUSED: *tracker='orbslam3'*box_rule needs the built-in tracker*none or mask"]
    )


@pytest.mark.parametrize(
    "call, line",
    [
        # none is the baseline every rho is measured against: the sweep runs it once, bare.
        (
            'depotbench_run("smoke", strategy="none", frames=3, settings={"k": 2})',
            "*REFUSED: *thresholds for 'none': the baseline takes no thresholds*",
        ),
        (
            'depotbench_run("smoke", strategy="box_rule", frames=3, settings={"kk": 2})',
            "*REFUSED: *unknown setting 'kk'; known: *box_dilation_px*",
        ),
        (
            'depotbench_run("smoke", strategy="mask", tracker="orbslam3", frames=3, settings={"k": 2})',
            "*REFUSED: *--set k: --slam orbslam3 takes only box_dilation_px, min_confidence",
        ),
        (
            'depotbench_run("smoke", strategy="box_rule", frames=3, budgets={"ate": {"max": 1}})',
            "*REFUSED: *unknown budget 'ate'*",
        ),
        (
            'depotbench_run("smoke", strategy="box_rule", frames=0)',
            "*REFUSED: *frames: Input should be greater than or equal to 1*",
        ),
    ],
    ids=["none-settings", "unknown-setting", "orbslam3-mask-setting", "unknown-budget", "zero-frames"],
)
def test_settings_and_values_that_cannot_run_are_refused_before_any_work(pytester, monkeypatch, call, line):
    """M9: strategy none with settings ignored them, then failed with "no run matches this
    check"; an unknown setting, budget or frame count was refused only after the sequence
    was generated (or not at all)."""
    _refused(pytester, monkeypatch, call).stdout.fnmatch_lines([line])


def test_a_run_without_its_row_is_an_error_naming_the_job():
    """C18: ``rows[0]`` of an empty list was an IndexError naming nothing."""
    from depotbench.eval.pytest_plugin import the_row

    row = {"strategy": "none", "settings": "{}"}
    assert the_row([row], "none", "depotbench_run('smoke')") is row
    with pytest.raises(InputError, match=r"depotbench_run\('smoke'\): .*no row for strategy 'box_rule'"):
        the_row([row], "box_rule", "depotbench_run('smoke')")


@pytest.mark.slow  # 11 s; external programs are gated by test_external_sweeps.py by default
@pytest.mark.render
def test_an_external_tracker_is_run_and_gated_from_pytest_twice_with_one_output_folder(pytester):
    """Issue 35: the user's own program in depotbench_run, with its parameters and budgets;
    a second session with the same --depotbench-dir resumes and passes again. A failing
    budget names the tracker and its parameter values."""
    from tests.conftest import REPO

    oracle = REPO / "tests" / "programs" / "oracle_slam.py"
    tracker = {
        "name": "oracle",
        "command": f"{sys.executable} {oracle} {{sequence}} {{detections}} {{parameters}} "
        "{trajectory} {keypoints}",
        "parameters": {"noise_m": 0.0, "margin_px": 4, "mode": "ok"},
    }
    pytester.makepyfile(
        f"""
        import pytest

        TRACKER = {tracker!r}

        def test_accurate(depotbench_run):
            row = depotbench_run("smoke", strategy="none", frames=3, tracker=TRACKER,
                                 parameters={{"noise_m": 0.0}}, budgets={{"ate_rmse_m": {{"max": 0.001}}}})
            assert row["tracker"] == "oracle" and row["failure"] is None

        def test_noisy_fails_naming_it(depotbench_run):
            with pytest.raises(pytest.fail.Exception, match="oracle.*noise_m=0.2"):
                depotbench_run("smoke", strategy="none", frames=3, tracker=TRACKER,
                               parameters={{"noise_m": 0.2}}, budgets={{"ate_rmse_m": {{"max": 0.001}}}})
        """
    )
    for _ in range(2):
        result = pytester.runpytest_subprocess(
            "--depotbench-dir=bench", "--depotbench-workers=1", "-p", "no:cacheprovider"
        )
        result.assert_outcomes(passed=2)


def test_a_gate_file_is_found_beside_the_test_that_names_it(pytester):
    """Issue 35 point 6: gate paths resolved against pytest's rootdir, not the test's file."""
    sub = pytester.mkdir("checks")
    (sub / "g.yaml").write_text(
        "gates: g\nrun:\n  sequences: [seq]\n  strategies: [none]\n"
        "checks:\n  - name: c\n    budgets: {lost_fraction: {max: 1}}\n"
    )
    from tests.sequences import write_sequence

    write_sequence(sub / "seq", n=3)  # any sequence: the claim is where the gate file is found
    (sub / "test_gate.py").write_text(
        "import pytest\n\n@pytest.mark.depotbench_gates('g.yaml')\n"
        "def test_gate(depotbench_gates):\n    assert depotbench_gates.report.passed\n"
    )
    result = pytester.runpytest_subprocess(  # once: a second run only reads the same rows back
        "checks/test_gate.py",
        "--depotbench-dir=bench",
        "--depotbench-workers=1",
        "-p",
        "no:cacheprovider",
    )
    result.assert_outcomes(passed=1)


@pytest.mark.render
def test_a_run_is_its_record_with_the_figures_derived_from_the_runs_beside_it(pytester):
    """depotbench_run returns a ScoredRun: the typed record the sweep stored, and rho taken
    against the none run of the same sequence (read back from the results database)."""
    pytester.makepyfile(
        """
        import sqlite3

        import pytest
        from depotbench.eval.metrics.record import RunRecord

        def test_typed(depotbench_run, depotbench_dir):
            run = depotbench_run("smoke", strategy="box_rule", frames=6, seed=2)
            assert isinstance(run.record, RunRecord) and run.strategy == "box_rule"
            assert run.ate_rmse_m == run["ate_rmse_m"] == run.record.ate_rmse_m
            assert run.lost_fraction == pytest.approx(1.0 - run.tracked_fraction)
            (database,) = (depotbench_dir / "runs").glob("*/results.sqlite")
            with sqlite3.connect(database) as db:
                ate = dict(db.execute("SELECT strategy, ate_rmse_m FROM runs"))
            assert run.rho_percent == pytest.approx(100 * (ate["none"] - ate["box_rule"]) / ate["none"])
            with pytest.raises(KeyError):
                run["no_such_figure"]
        """
    )
    result = pytester.runpytest_subprocess("--depotbench-workers=1", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1)
