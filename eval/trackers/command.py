"""Any SLAM program as a tracker, through a command template.

The template is split like a shell command line (``shlex``) and run without a
shell. Placeholders stand for whole words (arguments):

``{sequence}``      the sequence folder (a masked copy under ``mask``)
``{associations}``  its associations.txt (written when the folder has none)
``{settings}``      ORB-SLAM2/3 RGB-D settings for its camera
``{vocabulary}``    the ORB vocabulary (``depotbench vocab``)
``{trajectory}``    where the program must write its TUM trajectory; without this
                    placeholder it is read from ``CameraTrajectory.txt`` in the
                    program's working folder (ORB-SLAM2's ``rgbd_tum`` writes there)
``{detections}``    the run's boxes, faults applied (``depotbench.eval.trackers.protocol``)
``{keypoints}``     where the program may write its keypoint decisions, scored against
                    the exact ground truth like the built-in tracker's
``{map}``           where the program may write its map, a PLY point cloud in the frame
                    of its trajectory, scored like the built-in dense map (``--map``)
``{times}``         where the program may write the time each frame took (its track_ms)
``{parameters}``    a JSON file of the run's parameter values
``{NAME}``          the value of parameter NAME

e.g. ``rgbd_tum {vocabulary} {settings} {sequence} {associations}``. Frames with
a pose in the trajectory count as tracked. The bench times the program whole (wall and
CPU time); a time per frame is the program's to write (``{times}``).
docs/external-trackers.md is the whole contract, for the program's authors.

A placeholder must be a whole word, with no format spec or conversion (``{sequence:d}``
once raised a traceback, ``{sequence:>1000000000}`` built a 1 GB argument). Each value
reaches the program as exactly one argument, whatever its characters: a folder named
``x;rm -rf ~`` is just a name. Inside a word it would be text that a program may parse
again (``sh -c 'test -d {sequence}'`` ran the shell syntax of a hostile folder name),
and which programs do that (shells, ``python -c``, ``ssh``) cannot be told from here,
so the rule has no exceptions. A shell script takes the values as its arguments,
``sh -c 'cd "$1" && slam "$2"' sh {sequence} {settings}``, or from the environment:
every value is also in ``DEPOTBENCH_SEQUENCE``, ``DEPOTBENCH_ASSOCIATIONS``,
``DEPOTBENCH_SETTINGS``, ``DEPOTBENCH_TRAJECTORY``, ``DEPOTBENCH_DETECTIONS``,
``DEPOTBENCH_KEYPOINTS``, ``DEPOTBENCH_PARAMETERS``, ``DEPOTBENCH_PARAM_NAME`` for each
parameter and, when the template names ``{vocabulary}`` or ``DEPOTBENCH_VOCABULARY``
(building one takes minutes), ``DEPOTBENCH_VOCABULARY``. For the same reason a
placeholder may not be the code of an interpreter (``sh -c -x -- {sequence}``,
``python3 -c {sequence}``: ``INTERPRETERS``).

The program runs in a scratch folder (its working directory) in ``$TMPDIR``; a
program word with a slash (``./my_slam.sh``) is found from the folder depotbench was
started in, a bare name in ``PATH``. Other relative paths in the template are the
program's to resolve, from the scratch folder. The program, whatever it started in
its process group, and the scratch folder end with depotbench, SIGKILL included
(``depotbench.eval.trackers.reaper``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shlex
import shutil
import string
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.core.errors import InputError
from depotbench.core.files import MAX_SPEC_BYTES, read_text
from depotbench.eval.metrics.record import typed
from depotbench.eval.trackers import sandbox
from depotbench.eval.trackers.base import TrackerError, TrackerRun
from depotbench.eval.trackers.evidence import collect
from depotbench.eval.trackers.external import run_child, write_settings
from depotbench.eval.trackers.frames import FrameSource
from depotbench.eval.trackers.placeholders import PLACEHOLDERS
from depotbench.eval.trackers.protocol import (
    read_keypoints,
    read_map,
    read_times,
    read_trajectory,
    write_detections,
)
from depotbench.eval.trackers.reaper import Scratch
from depotbench.eval.trackers.sequence_view import SequenceGuard
from depotbench.sim.camera import OrbSlamSettings, orbslam_yaml
from depotbench.sim.sequence import Sequence, timestamp_name
from depotbench.slam.types import TrackingState

PARAMETER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.]{0,63}")
"""A parameter's name: also a placeholder, and ``DEPOTBENCH_PARAM_`` + its upper case."""
DEFAULT_TRAJECTORY = "CameraTrajectory.txt"
ENVIRONMENT_PREFIX = "DEPOTBENCH_"


@dataclass(frozen=True)
class Interpreter:
    """How a program that runs code from its command line is told that code, so that a
    placeholder as that code can be refused: a shell's ``-c`` is a flag (its script is the
    first word after all its options: ``sh -c -x -- SCRIPT``); python's ``-c`` and perl's
    ``-e`` take the next word as the script."""

    script: str
    """Option letters that give a script (``-c``, clusters such as ``-ec`` included)."""
    flag: bool
    """The script is the first word after the options (a shell), not the option's value."""
    takes: str = ""
    """Option letters that take the next word as their value (``sh -o errexit``)."""
    long_takes: frozenset[str] = frozenset()
    """Long options that take the next word (``bash --rcfile FILE``)."""
    ends: str = ""
    """Option letters after which the words are another program's (``python -m MODULE``)."""


SHELL = Interpreter("c", flag=True, takes="oO", long_takes=frozenset({"--rcfile", "--init-file"}))
SHELLS = frozenset({"sh", "bash", "dash", "zsh", "ksh", "mksh", "ash", "yash", "fish", "busybox", "su"})
INTERPRETERS: dict[str, Interpreter] = {
    **dict.fromkeys(SHELLS, SHELL),
    "python": Interpreter("c", flag=False, takes="WX", ends="m"),
    "perl": Interpreter("eE", flag=False),
    "ruby": Interpreter("e", flag=False),
    "node": Interpreter("ep", flag=False, takes="r"),
}
"""Programs that run a word of their command line as code, by name (a version suffix,
``python3.11``, ``bash5``, and a folder are ignored). Which other programs parse a value
again (``ssh``, ``make``) cannot be told from here: for them the rule is the environment."""


def parse_template(template: str, parameters: tuple[str, ...] = ()) -> list[str]:
    """The template's words, refused when empty, unbalanced, naming unknown placeholders,
    or using one in any way but as a whole word (see the module's docstring)."""
    known = (*PLACEHOLDERS, *parameters)
    try:
        words = shlex.split(template)
    except ValueError as exc:
        raise InputError(f"--command {template!r}: {exc}") from None
    if not words:
        raise InputError("--command: the template is empty")
    for word in words:
        _check_word(word, known)
    _refuse_shell_scripts(words, known)
    return words


def check_parameter_names(names: tuple[str, ...]) -> None:
    for name in names:
        if name in PLACEHOLDERS:
            raise InputError(
                f"parameter {name!r}: {{{name}}} is one of the bench's placeholders; "
                "give your parameter another name"
            )
        if not PARAMETER_NAME.fullmatch(name):
            raise InputError(f"parameter {name!r}: give a name of letters, digits, _ and . (64 at most)")


def _check_word(word: str, known: tuple[str, ...]) -> None:
    try:
        fields = [(name, spec, conversion) for _, name, spec, conversion in string.Formatter().parse(word)]
    except ValueError as exc:
        raise InputError(f"--command: {word!r}: {exc}") from None
    names = [name for name, _, _ in fields if name is not None]
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise InputError(
            f"--command: unknown placeholder {{{unknown[0]}}}; "
            f"known: {', '.join('{' + p + '}' for p in known)}"
        )
    for name, spec, conversion in fields:
        if name is not None and (spec or conversion):
            raise InputError(
                f"--command: {word!r}: a placeholder takes no format spec or conversion (write {{{name}}})"
            )
    if names and word != "{" + names[0] + "}":
        raise InputError(
            f"--command: {word!r}: a placeholder must be a whole word: its value is passed as one "
            f"argument and never through a shell; a shell script takes it as an argument "
            f'(sh -c \'cd "$1" && ...\' sh {{{names[0]}}}) or from "${ENVIRONMENT_PREFIX}{names[0].upper()}"'
        )


def _refuse_shell_scripts(words: list[str], known: tuple[str, ...]) -> None:
    """``sh -c {sequence}`` would run a folder's name as shell commands: a placeholder is
    never the code of an interpreter anywhere in the command (``env A=B sh -c -- {x}``,
    ``timeout 5 bash -o errexit -c {x}``, ``busybox sh -xc {x}``, ``python3 -c {x}``)."""
    for at, program in enumerate(words):
        interpreter = INTERPRETERS.get(_interpreter_name(program))
        if interpreter is None:
            continue
        for index, option in _scripts(words, at, interpreter):
            if _placeholder(words[index], known):
                name = Path(program).name
                raise InputError(
                    f"--command: {words[index]} is the script of {name} {option}: "
                    f"{'a shell' if interpreter.flag else name} would run its value as commands; "
                    f"pass it as an argument (sh -c 'cd \"$1\" && ...' sh {words[index]}) or "
                    f"from the environment (${ENVIRONMENT_PREFIX}{words[index][1:-1].upper()})"
                )


def _interpreter_name(word: str) -> str:
    return re.sub(r"[0-9.]+$", "", Path(word).name)


def _scripts(words: list[str], at: int, interpreter: Interpreter) -> list[tuple[int, str]]:
    """The indexes of the words the interpreter ``words[at]`` runs as code, with the option
    that says so."""
    found: list[tuple[int, str]] = []
    flagged = None
    i = at + 1
    while i < len(words):
        word = words[i]
        if word == "--":
            i += 1
            break
        if len(word) < 2 or word[0] not in "-+":
            break  # the first word that is no option: a script file, or the script
        i += 1
        if word.startswith("--"):
            i += word in interpreter.long_takes
            continue
        for k, letter in enumerate(word[1:], start=1):
            last = k == len(word) - 1
            if letter in interpreter.ends:
                return found
            if letter in interpreter.script and interpreter.flag:
                flagged = word
            elif letter in interpreter.script or letter in interpreter.takes:
                if last and letter in interpreter.script and i < len(words):
                    found.append((i, word))
                i += last  # the value is the next word, or the rest of this one
                break
    if flagged is not None and i < len(words):
        found.append((i, flagged))
    return found


def _placeholder(word: str, known: tuple[str, ...] = PLACEHOLDERS) -> str | None:
    """The placeholder a checked word stands for, None for a literal word."""
    return word[1:-1] if word[1:-1] in known and word == "{" + word[1:-1] + "}" else None


def uses(words: list[str], placeholder: str) -> bool:
    """Whether the template names the placeholder or its environment variable."""
    variable = ENVIRONMENT_PREFIX + placeholder.upper()
    return any(_placeholder(word) == placeholder or variable in word for word in words)


def resolve_program(word: str, cwd: Path) -> tuple[str, str]:
    """The program to start and how to name it in an error: a word with a slash is a
    path from ``cwd`` (the program runs in a scratch folder), a bare name is found in PATH."""
    if _placeholder(word) is not None or "/" not in word:
        return word, f"{word!r} (looked in PATH)" if _placeholder(word) is None else repr(word)
    path = cwd / word
    return str(path), f"{word!r} (looked for {path})" if word != str(path) else repr(word)


def check_program(words: list[str], cwd: Path) -> None:
    """Refuse, before any run, a program that is missing or cannot be executed (a
    placeholder as the program is the run's to resolve)."""
    if _placeholder(words[0]) is not None:
        return
    program, shown = resolve_program(words[0], cwd)
    found = shutil.which(program)
    if found is None:
        path = Path(program)
        with_slash = "/" in program  # a bare name was looked for in PATH, not here
        why = (
            "is a directory"
            if with_slash and path.is_dir()
            else "is not executable"
            if path.is_file()
            else "does not exist"
        )
        raise InputError(f"--command: the program {shown} {why}")


def _environment_name(name: str) -> str:
    return "PARAM_" + name.upper().replace(".", "_")


class CommandTracker:
    name = "cmd"

    def __init__(
        self,
        template: str,
        vocabulary: Callable[[], Path] | None = None,
        timeout_s: float = 3600.0,
        *,
        label: str = "cmd",
        parameters: tuple[tuple[str, str], ...] = (),
        settings: SettingsTemplate | None = None,
        env: tuple[tuple[str, str], ...] = (),
    ) -> None:
        names = tuple(name for name, _ in parameters)
        check_parameter_names(names)
        self.words = parse_template(template, names)
        self.known = (*PLACEHOLDERS, *names)
        # Now, while the working directory is still the user's: the program runs elsewhere.
        self.program, self.shown = resolve_program(self.words[0], Path.cwd())
        self.vocabulary = vocabulary
        self.timeout_s = timeout_s
        self.label = label
        self.parameters = dict(parameters)
        self.settings = settings
        self.env = dict(env)

    def run(self, frames: FrameSource, progress: bool) -> TrackerRun:
        sequence = frames.sequence
        what = f"{self.label} {Path(self.words[0]).name}" if self.label == "cmd" else self.label
        try:
            scratch = Scratch("depotbench-cmd-")
        except OSError as exc:
            raise TrackerError(
                f"{self.label}: cannot make a scratch folder in {exc.filename}: {exc.strerror}"
            ) from None
        with scratch:
            values = self._values(frames, scratch.path)
            argv = [self.program, *(self._word(word, values) for word in self.words[1:])]
            if _placeholder(self.words[0], self.known) is not None:
                argv[0] = values[_placeholder(self.words[0], self.known)]
            env = self._environment(values)
            guard = SequenceGuard.before(sequence, Path(values["sequence"]))
            changed = None
            try:
                try:
                    child = run_child(
                        argv,
                        what=what,
                        cwd=scratch.path,
                        timeout_s=self.timeout_s,
                        frames=len(sequence),
                        progress=progress,
                        env=env,
                        group=scratch.group,
                        program=self.shown,
                    )
                finally:  # a failed program may have changed it too
                    changed = guard.change(what)
                if not scratch.path.is_dir():
                    raise TrackerError(
                        f"{what}: removed its working folder (the scratch folder the bench made for it)",
                        child.log,
                    )
                if changed is not None:
                    raise TrackerError(changed, child.log)
                trajectory = Path(values["trajectory"])
                if not os.path.lexists(trajectory):
                    raise TrackerError(f"{what}: wrote no trajectory ({trajectory.name})", child.log)
                try:
                    poses = read_trajectory(trajectory, sequence)
                    keypoints = Path(values["keypoints"])
                    decisions = read_keypoints(keypoints, sequence) if os.path.lexists(keypoints) else None
                    drawn = Path(values["map"])
                    cloud = read_map(drawn) if os.path.lexists(drawn) else None
                    timed = Path(values["times"])
                    times = read_times(timed, sequence) if os.path.lexists(timed) else None
                except InputError as exc:  # what the program wrote cannot be read: its failure, named
                    raise TrackerError(f"{what}: {_relative(exc, scratch.path)}", child.log) from None
            except TrackerError as exc:  # kept now: the scratch folder goes with the run
                reason = str(exc) if changed is None or changed == str(exc) else f"{exc}; {changed}"
                evidence = collect(scratch.path, argv, self._set_here(env))
                raise TrackerError(reason, exc.log, evidence) from None
        run = _tracker_run(frames, poses, child.wall_s)
        return dataclasses.replace(
            run,
            track_ms=run.track_ms if times is None else times,
            decisions=decisions,
            peak_memory_mb=child.peak_memory_mb,
            cpu_s=child.cpu_s,
            log=child.log,
            map_points=None if cloud is None else cloud[0],
            map_colours=None if cloud is None else cloud[1],
        )

    def _word(self, word: str, values: dict[str, str]) -> str:
        name = _placeholder(word, self.known)
        return values[name] if name is not None else word.format()  # a literal: {{ is {

    def _values(self, frames: FrameSource, scratch: Path) -> dict[str, str]:
        """The placeholders' values; what they name is written into ``scratch``."""
        try:
            folder = frames.folder(scratch).resolve()
            associations = folder / "associations.txt"
            if not associations.is_file():
                associations = _write_associations(frames, scratch / "associations.txt")
            settings = scratch / "settings.yaml"
            if self.settings is None:
                write_settings(frames.sequence, settings)
            else:
                settings.write_text(self.settings.render(frames.sequence, self.parameters), encoding="utf-8")
            detections = write_detections(
                scratch / "detections.txt", frames.sequence, frames.all_detections()
            )
            parameters = scratch / "parameters.json"
            values = {name: typed(text) for name, text in sorted(self.parameters.items())}
            parameters.write_text(json.dumps(values, indent=2) + "\n", encoding="utf-8")
        except OSError as exc:
            raise TrackerError(
                f"{self.label}: cannot write to the scratch folder {scratch}: {exc.strerror}"
            ) from None
        trajectory = scratch / ("trajectory.txt" if uses(self.words, "trajectory") else DEFAULT_TRAJECTORY)
        values = {
            "sequence": str(folder),
            "associations": str(associations),
            "settings": str(settings),
            "trajectory": str(trajectory),
            "detections": str(detections),
            "keypoints": str(scratch / "keypoints.txt"),
            "map": str(scratch / "map.ply"),
            "times": str(scratch / "times.txt"),
            "parameters": str(parameters),
            "vocabulary": "",
        }
        if uses(self.words, "vocabulary"):
            if self.vocabulary is None:
                raise TrackerError("--command uses {vocabulary}, but no vocabulary was given")
            values["vocabulary"] = str(self.vocabulary().resolve())
        return values | self.parameters

    def _set_here(self, env: dict[str, str]) -> dict[str, str]:
        """What of ``env`` the bench set: the tracker's own variables and the values."""
        return {
            name: value
            for name, value in env.items()
            if name in self.env or (name.startswith(ENVIRONMENT_PREFIX) and os.environ.get(name) != value)
        }

    def _environment(self, values: dict[str, str]) -> dict[str, str]:
        """depotbench's environment, the tracker's own variables, and the values as
        ``DEPOTBENCH_SEQUENCE`` and so on (one left unset when it has none, so that a
        stale one from outside does not pass)."""
        env = dict(os.environ) | self.env
        for name, value in values.items():
            variable = ENVIRONMENT_PREFIX + (
                name.upper() if name in PLACEHOLDERS else _environment_name(name)
            )
            if value:
                env[variable] = value
            else:
                env.pop(variable, None)
        return env


def _relative(exc: InputError, scratch: Path) -> str:
    """An error about a file the program wrote, naming the file, not the scratch folder
    (it is gone by the time anyone reads the line)."""
    return str(exc).replace(f"{scratch}/", "")


class SettingsTemplate:
    """A Jinja2 template of a program's settings file, rendered per run with the camera
    (``camera``), the run's parameters (``params``) and ORB-SLAM's camera block and whole
    default file (``orbslam_camera``, ``orbslam_settings``). Names it is not given are
    errors (``StrictUndefined``): a misspelt one would otherwise render as nothing.

    It is compiled and rendered only in Jinja2's sandbox, in a child process with bounded
    memory, time and output (``depotbench.eval.trackers.sandbox``): a settings file is
    data, and nothing in it may reach the bench's host. Every failure is one line naming
    the tracker (``label``) and the file."""

    def __init__(self, path: Path, text: str, label: str = "cmd") -> None:
        self.path = path
        self.text = text
        self.label = label
        self._render(None, "does not parse")

    @classmethod
    def load(cls, path: Path, label: str = "cmd") -> SettingsTemplate:
        try:
            return cls(path, read_text(path, MAX_SPEC_BYTES, "settings template"), label)
        except FileNotFoundError:
            raise InputError(f"{label}: {path}: the settings template does not exist") from None

    def render(self, sequence: Sequence, parameters: dict[str, str]) -> str:
        k = sequence.intrinsics
        whole = orbslam_yaml(k, OrbSlamSettings(fps=sequence.fps)).splitlines()
        camera_block = [line for line in whole if line.startswith(("Camera.", "DepthMapFactor"))]
        variables = {
            "camera": {
                "fx": k.fx,
                "fy": k.fy,
                "cx": k.cx,
                "cy": k.cy,
                "width": k.width,
                "height": k.height,
                "fps": sequence.fps,
                "depth_scale": k.depth_scale,
                "distortion": k.distortion_by_name,
            },
            "params": {name: typed(text) for name, text in parameters.items()},
            "orbslam_camera": "\n".join(camera_block),
            "orbslam_settings": "\n".join(line for line in whole if not line.startswith("%YAML")),
        }
        return self._render(variables, "cannot be rendered")

    def _render(self, variables: dict | None, failing: str) -> str:
        """The output, capped like a spec file (``MAX_SPEC_BYTES``): the program reads it."""
        try:
            return sandbox.render(self.text, variables, MAX_SPEC_BYTES)
        except sandbox.TemplateRefused as exc:
            where = f"{self.path}:{exc.line}" if exc.line else str(self.path)
            raise InputError(
                f"{self.label}: {where}: the settings template {failing}: {exc.reason}"
            ) from None


def _write_associations(frames: FrameSource, path: Path) -> Path:
    sequence = frames.sequence
    path.write_text(
        "".join(
            f"{timestamp_name(f.timestamp_s)} {f.rgb_path.relative_to(sequence.root)} "
            f"{timestamp_name(f.depth_timestamp_s)} {f.depth_path.relative_to(sequence.root)}\n"
            for f in sequence.frames
        ),
        encoding="utf-8",
    )
    return path


def _tracker_run(frames: FrameSource, poses: tuple[np.ndarray | None, ...], total_s: float) -> TrackerRun:
    sequence = frames.sequence
    first = next((i for i, pose in enumerate(poses) if pose is not None), len(poses))
    states = tuple(
        TrackingState.OK
        if pose is not None
        else (TrackingState.NOT_INITIALIZED if i < first else TrackingState.LOST)
        for i, pose in enumerate(poses)
    )
    return TrackerRun(
        timestamps_s=sequence.timestamps_s,
        states=states,
        poses=tuple(poses),
        track_ms=np.full(len(sequence), np.nan),
        keyframes=None,
        total_s=total_s,
    )


def build(tracker, config, progress: bool, stages: list | None = None) -> CommandTracker:
    """The registry's entry point: its template, parameter names and settings template are
    checked here, so ``check`` refuses a bad one before any run."""
    from depotbench.eval.trackers.vocabulary import default_vocabulary

    if not tracker.command:
        raise InputError("--slam cmd needs --command TEMPLATE")
    _refuse_nul(tracker)
    settings = (
        SettingsTemplate.load(tracker.settings_template, tracker.label) if tracker.settings_template else None
    )
    return CommandTracker(
        tracker.command,
        (lambda: tracker.vocabulary or default_vocabulary(progress)),
        tracker.timeout_s,
        label=tracker.label,
        parameters=tracker.parameters,
        settings=settings,
        env=tracker.env,
    )


def _refuse_nul(tracker) -> None:
    """A NUL byte ends a string on its way to a program (``execve``): one in the command,
    the environment or a parameter ended a whole sweep with ``ValueError: embedded null
    byte``; it is refused here, naming the field."""
    fields = [
        ("command", tracker.command),
        *((f"env: {name!r}", f"{name}={value}") for name, value in tracker.env),
        *((f"parameter {name!r}", value) for name, value in tracker.parameters),
        ("settings", str(tracker.settings_template or "")),
        ("vocabulary", str(tracker.vocabulary or "")),
    ]
    for field, text in fields:
        if "\0" in text:
            raise InputError(f"{field}: holds a NUL byte, which cannot reach a program")


def check(tracker, camera_sequence: Sequence | None = None) -> None:
    """An unknown placeholder or parameter, a missing or non-executable program, a settings
    template that does not parse or names what it is not given (rendered on
    ``camera_sequence``)."""
    program = build(tracker, None, False)
    check_program(program.words, Path.cwd())
    if program.settings is not None and camera_sequence is not None:
        program.settings.render(camera_sequence, dict(tracker.parameters))
