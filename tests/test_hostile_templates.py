"""A user's settings and command templates against a hostile author (issue 50).

A settings template is data: it renders in Jinja2's immutable sandbox, in a child with
bounded memory, time and output, and every failure is one line naming the tracker and
the file (N1, O1, O9, N12, N21), under the template directly, ``validate``, ``run`` and
the pytest plugin. A shell's script is never a placeholder, however the shell is
reached (N2, S3). The probe's findings are in ../shared/reliability-probe-2.md.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.trackers.command import SettingsTemplate, parse_template
from depotbench.sim.sequence import Sequence

from tests.sequences import write_sequence
from tests.test_output import cli, one_error_line

HANG_GUARD_S = 10.0
"""A hostile template is refused in about 0.5 s (a child's start); this only catches a hang."""
TOUCH = "touch {mark}"


def hostile(mark: Path) -> dict[str, str]:
    """The probe's hostile templates; those that reach the host would create ``mark``."""
    touch = TOUCH.format(mark=mark)
    return {
        "cycler": f"{{{{ cycler.__init__.__globals__.os.popen('{touch}').read() }}}}",
        "self": f"{{{{ self.__init__.__globals__.__builtins__.__import__('os').system('{touch}') }}}}",
        "lipsum": f"{{{{ lipsum.__globals__['os'].popen('{touch}').read() }}}}",
        "joiner": f"{{{{ joiner.__init__.__globals__.os.popen('{touch}').read() }}}}",
        "namespace": f"{{{{ namespace.__init__.__globals__.os.popen('{touch}').read() }}}}",
        "attr": "{{ ''|attr('__class__') }}",
        "include": "{% include 'x' %}",
        "import": "{% import 'x' as y %}",
        "extends": "{% extends 'x' %}",
        "format": "{{ '{0.__class__.__mro__}'.format(1) }}",
        "recursion": "{% macro f(n) %}{{ f(n) }}{% endmacro %}{{ f(1) }}",
        "string-bomb": "{{ 'x' * 4000000000 }}",
        "power-bomb": "{{ 10 ** (10 ** 9) }}",
        "range-bomb": "{{ range(100000000)|list }}",
        "loop-bomb": "{% for i in range(10**6) %}{{ 'y' * 1000 }}{% endfor %}",
        "output-bomb": "{% for i in range(100000) %}{{ 'y' * 1000 }}{% endfor %}",
        "concat-bomb": "{% set x = 'x' * 1000000 %}" + "{% set x = x ~ x %}" * 12 + "{{ x|length }}",
        "width-bomb": "{{ 'x'|center(4000000000) }}",
        "spin": "{% for i in range(100000) %}{% for j in range(100000) %}{% endfor %}{% endfor %}",
        "zero": "{{ 1 / 0 }}",
    }


HOSTILE = tuple(hostile(Path("/x")))


@pytest.fixture(scope="module")
def camera_sequence(tmp_path_factory: pytest.TempPathFactory) -> Sequence:
    root = tmp_path_factory.mktemp("camera") / "seq"
    write_sequence(root, n=2, with_flow=False)
    return Sequence.open(root)


@pytest.mark.parametrize("name", HOSTILE)
def test_a_hostile_settings_template_is_one_line_and_reaches_nothing(
    name: str, camera_sequence: Sequence, tmp_path: Path
):
    """N1/O1/O9/N12/N21: a plain jinja2.Environment ran ``os.popen`` from ``cycler``,
    raised TypeError (include), RecursionError, MemoryError, took 20 s for a range, and
    rendered a 100 MB loop; each is now refused in one line naming tracker and file."""
    mark = tmp_path / "X"
    path = tmp_path / f"{name}.j2"
    started = time.monotonic()
    with pytest.raises(InputError) as refused:
        SettingsTemplate(path, hostile(mark)[name], "mine").render(camera_sequence, {})
    elapsed = time.monotonic() - started
    print(f"{name}: refused in {elapsed:.2f} s: {refused.value}")
    assert elapsed < HANG_GUARD_S
    line = str(refused.value)
    assert "\n" not in line and "Traceback" not in line
    assert line.startswith(f"mine: {path}") and "the settings template" in line
    assert not mark.exists()


@pytest.mark.parametrize(
    "text, why",
    [
        ("a: 1\n{% for %}\n", ":2: the settings template does not parse"),
        ("{{ nothing }}", "'nothing' is undefined"),
        ("{{ camera.fx.real.__class__ }}", "unsafe"),
    ],
)
def test_a_template_error_names_the_tracker_the_file_and_the_line(
    text: str, why: str, camera_sequence: Sequence, tmp_path: Path
):
    with pytest.raises(InputError, match="^mine: ") as refused:
        SettingsTemplate(tmp_path / "t.j2", text, "mine").render(camera_sequence, {})
    assert why in str(refused.value) and str(tmp_path / "t.j2") in str(refused.value)


def test_a_sandboxed_template_still_renders_what_a_settings_file_needs(
    camera_sequence: Sequence, tmp_path: Path
):
    text = (
        "fx: {{ camera.fx }}\n{% for name, v in camera.distortion.items() %}{{ name }}={{ v }} {% endfor %}\n"
        "{% set ns = namespace(n=0) %}{% for i in range(3) %}{% set ns.n = ns.n + i %}{% endfor %}"
        "n: {{ ns.n }} {{ params.alpha * 2 }} {{ 'ab' * 2 }} {{ 2 ** 10 }}\n{{ orbslam_camera }}\n"
    )
    out = SettingsTemplate(tmp_path / "t.j2", text).render(camera_sequence, {"alpha": "1.5"})
    k = camera_sequence.intrinsics
    assert out.startswith(f"fx: {k.fx}\nk1=") and "n: 3 3.0 abab 1024\n" in out
    assert f"Camera.fx: {k.fx}" in out.replace(".0\n", "\n") or f"Camera.fx: {k.fx:g}" in out


def test_a_rendering_is_made_once_per_process_and_a_refusal_every_time(
    camera_sequence: Sequence, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """A sweep renders a template for every job: the same request gives the child's first
    answer back (a rendering is a function of its request), a refusal is never kept."""
    from depotbench.eval.trackers import sandbox

    started = []
    real = sandbox._render
    monkeypatch.setattr(sandbox, "_render", lambda *a: started.append(a) or real(*a))
    monkeypatch.setattr(sandbox, "_rendered", {})
    template = SettingsTemplate(tmp_path / "t.j2", "a: {{ params.a }}\n")
    first = [template.render(camera_sequence, {"a": "1"}) for _ in range(3)]
    other = template.render(camera_sequence, {"a": "2"})
    assert first == ["a: 1\n"] * 3 and other == "a: 2\n"
    assert len(started) == 3  # compiled, then rendered twice
    refused = SettingsTemplate(tmp_path / "z.j2", "{{ 1 / 0 }}")
    for _ in range(2):
        with pytest.raises(InputError, match="ZeroDivisionError|division"):
            refused.render(camera_sequence, {})
    assert len(started) == 6


# -- the entry points: validate (a child process), run, the pytest plugin ---------------------


def _spec(folder: Path, template: Path, sequence: Path) -> Path:
    spec = folder / "spec.yaml"
    spec.write_text(
        f"sweep: hostile\nsequences: [{sequence}]\nstrategies: [none]\ntrackers:\n"
        f"  - name: mine\n    command: 'true {{sequence}}'\n    settings: {template.name}\n"
    )
    return spec


def test_validate_of_a_sweep_with_a_hostile_template_runs_nothing(camera_sequence: Sequence, tmp_path: Path):
    """O1: ``depotbench validate`` created X from the cycler template."""
    mark = tmp_path / "X"
    template = tmp_path / "hostile.j2"
    template.write_text(hostile(mark)["cycler"])
    spec = _spec(tmp_path, template, camera_sequence.root)
    done = subprocess.run(
        [sys.executable, "-m", "depotbench.eval.cli.main", "validate", str(spec)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode != 0, done.stdout
    one_error_line(done.stderr, "mine", str(template), "__init__", "unsafe")
    assert not mark.exists()


def test_run_with_a_hostile_template_runs_nothing_and_writes_nothing(
    camera_sequence: Sequence, tmp_path: Path, capsys
):
    mark = tmp_path / "X"
    template = tmp_path / "hostile.j2"
    template.write_text(hostile(mark)["lipsum"])
    out = tmp_path / "r"
    code, _, err = cli(
        capsys,
        "run",
        camera_sequence.root,
        "-o",
        out,
        "--slam",
        "cmd",
        "--command",
        "true {sequence}",
        "--settings-template",
        template,
    )
    assert code == 2
    one_error_line(err, str(template), "__globals__", "unsafe")
    assert not mark.exists() and not out.exists()


@pytest.mark.render
@pytest.mark.slow  # 13 s: it generates a sequence
def test_the_pytest_plugin_refuses_a_hostile_template_in_one_line(pytester, tmp_path: Path):
    mark = tmp_path / "X"
    (pytester.path / "hostile.j2").write_text(hostile(mark)["namespace"])
    tracker = {"name": "mine", "command": "true {sequence}", "settings": "hostile.j2"}
    pytester.makepyfile(
        textwrap.dedent(
            f"""
            import pytest
            from depotbench.core.errors import InputError

            def test_refused(depotbench_run):
                with pytest.raises(InputError) as caught:
                    depotbench_run("smoke", strategy="none", frames=3, tracker={tracker!r})
                print("REFUSED:", caught.value)
                assert "\\n" not in str(caught.value)
            """
        )
    )
    result = pytester.runpytest_subprocess("--depotbench-workers=1", "-p", "no:cacheprovider", "-s")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["*REFUSED: *mine*hostile.j2*the settings template*unsafe*"])
    assert not mark.exists()


# -- N2/S3: a placeholder is never an interpreter's code ----------------------------------------


@pytest.mark.parametrize(
    "template",
    [
        "sh -c -- {sequence}",
        "bash -c -- {sequence}",
        "sh -c -x {sequence}",
        "env -- sh -c -- {sequence}",
        "env A=B sh -c {sequence}",
        "/usr/bin/env sh -c {sequence}",
        "busybox sh -c {sequence}",
        "nice sh -c {sequence}",
        "timeout 5 sh -c {sequence}",
        "sh -xc {sequence}",
        "bash -o errexit -c {sequence}",
        "bash +o posix -e -c -- {settings}",
        "bash --rcfile /dev/null -c {sequence}",
        "python3 -c {sequence}",
        "python3.11 -W ignore -c {sequence}",
        "perl -e 1 -e {sequence}",
    ],
)
def test_a_placeholder_is_never_the_script_of_an_interpreter(template: str):
    """N2: options between -c and the script, ``--``, and a shell behind env, nice,
    timeout or busybox slipped past the check of the word right after ``-c``."""
    with pytest.raises(InputError, match="would run its value as commands") as refused:
        parse_template(template)
    assert "{sequence}" in str(refused.value) or "{settings}" in str(refused.value)


@pytest.mark.parametrize(
    "template",
    [
        "sh -c 'exec slam \"$1\"' sh {sequence}",
        "sh -c -- 'exec slam \"$1\"' sh {sequence}",
        "bash -o errexit my_slam.sh {sequence}",
        "python3 my_slam.py -c {settings}",
        "python3 -m my_slam -c {settings}",
        "slam -c {settings}",
    ],
)
def test_a_placeholder_as_an_argument_of_an_interpreter_is_fine(template: str):
    assert parse_template(template)


def test_a_hostile_folder_name_reaches_no_shell_through_env_and_options(tmp_path: Path, capsys):
    """N2 end to end: ``env -- sh -c -- {sequence}`` ran a folder's name as commands."""
    hostile_folder = tmp_path / "s;touch X;"
    write_sequence(hostile_folder, n=2, with_flow=False)
    code, _, err = cli(
        capsys,
        "run",
        hostile_folder,
        "-o",
        tmp_path / "r",
        "--slam",
        "cmd",
        "--command",
        "env -- sh -c -- {sequence}",
    )
    assert code == 2
    one_error_line(err, "{sequence} is the script of sh -c", "a shell would run its value as commands")
    assert not (tmp_path / "X").exists() and not Path("X").exists() and not (tmp_path / "r").exists()


# -- N22: a NUL byte never reaches a program ------------------------------------------------------


@pytest.mark.parametrize(
    "entry, field",
    [
        ('    command: "true {sequence}"\n    env: {A: "a\\0b"}\n', "env: 'A'"),
        ('    command: "true\\0x {sequence}"\n', "command"),
        ('    command: "true {sequence}"\n    parameters: {p: "a\\0b"}\n', "parameter 'p'"),
    ],
)
def test_a_nul_byte_in_a_trackers_fields_is_refused_by_validate(
    entry: str, field: str, camera_sequence: Sequence, tmp_path: Path, capsys
):
    """N22: validate said ok, then the sweep died with ``ValueError: embedded null byte``."""
    spec = tmp_path / "spec.yaml"
    spec.write_text(
        f"sweep: nul\nsequences: [{camera_sequence.root}]\nstrategies: [none]\n"
        f"trackers:\n  - name: mine\n{entry}"
    )
    code, _, err = cli(capsys, "validate", spec)
    assert code == 2
    one_error_line(err, "trackers.0 (mine)", field, "NUL byte")


# -- O12: what a confused program or configuration is told ------------------------------------------


def test_a_program_that_removes_its_working_folder_is_a_failed_run_saying_so(
    camera_sequence: Sequence, tmp_path: Path, capsys
):
    """O12: the run ended with ``error: /tmp/depotbench-cmd-...: No such file or directory``."""
    remover = "sh -c 'rm -rf \"$PWD\"' sh {sequence}"
    code, _, err = cli(
        capsys, "run", camera_sequence.root, "-o", tmp_path / "r", "--slam", "cmd", "--command", remover
    )
    assert code != 0 and "Traceback" not in err
    assert "removed its working folder" in err and "No such file or directory" not in err, err


def test_a_folder_as_the_program_is_named_a_directory(
    camera_sequence: Sequence, tmp_path: Path, capsys, monkeypatch
):
    (tmp_path / "my_slam").mkdir()
    monkeypatch.chdir(tmp_path)
    code, _, err = cli(
        capsys,
        "run",
        camera_sequence.root,
        "-o",
        tmp_path / "r",
        "--slam",
        "cmd",
        "--command",
        "./my_slam {sequence}",
    )
    assert code == 2
    one_error_line(err, "the program './my_slam'", "is a directory")


def test_a_parameter_named_like_a_placeholder_is_told_so_plainly(
    camera_sequence: Sequence, tmp_path: Path, capsys
):
    code, _, err = cli(
        capsys,
        "run",
        camera_sequence.root,
        "-o",
        tmp_path / "r",
        "--slam",
        "cmd",
        "--command",
        "true {sequence}",
        "--param",
        "trajectory=1",
    )
    assert code == 2
    line = one_error_line(err, "parameter 'trajectory'", "{trajectory} is one of the bench's placeholders")
    assert "letters" not in line


# -- O11: a process that leaves the program's group ------------------------------------------------

ESCAPER = """
import shutil, subprocess, sys
sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True)
open(sys.argv[3], "w").write(str(sleeper.pid))
shutil.copy(sys.argv[1] + "/groundtruth.txt", sys.argv[2])
"""


@pytest.mark.skipif(not Path("/proc/self/fd").exists(), reason="reads /proc")
def test_a_process_that_escapes_the_programs_group_is_named_and_ended_without_a_stall(
    camera_sequence: Sequence, tmp_path: Path, capsys, caplog
):
    """O11: a setsid grandchild holding the program's output kept the bench waiting 5 s a
    pipe (10 s a run) and was never mentioned."""
    from tests.test_external_program import alive, gone_within

    script = tmp_path / "escaper.py"
    script.write_text(ESCAPER)
    pid_file = tmp_path / "pid"
    command = f"{sys.executable} {script} {{sequence}} {{trajectory}} {pid_file}"
    started = time.monotonic()
    with caplog.at_level("WARNING", logger="depotbench"):
        code, out, err = cli(
            capsys, "run", camera_sequence.root, "-o", tmp_path / "r", "--slam", "cmd", "--command", command
        )
    elapsed = time.monotonic() - started
    print(f"the run took {elapsed:.1f} s")
    assert code == 0, err
    pid = int(pid_file.read_text())
    warned = [r.getMessage() for r in caplog.records if "outlived it" in r.getMessage()]
    assert len(warned) == 1 and f"process {pid}," in warned[0] and "was killed" in warned[0], warned
    assert gone_within(5.0, lambda: not alive(pid))
    assert "outlived it" in (tmp_path / "r" / "program.log").read_text()
    assert elapsed < 2 * 5.0  # the stall it had: 5 s for each of two pipes
