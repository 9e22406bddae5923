"""``depotbench validate``: a linter for every file the bench reads, run before a long run.

Each problem is a line of its own, ``FILE:LINE: field: what is wrong``, and all of a file's
problems come in one pass: pydantic gives every field error of a model at once, and each
semantic check (a threshold that is no setting, a budget outside its figure's values, a
sequence folder that does not open, a matrix of zero runs) adds its line instead of
stopping the others. A valid file gets one line saying what it is; a sweep's says the size
of its matrix (``4 sequences x 1 tracker x 1 detector x 8 variants = 32 runs``).

A kind is an entry in ``KINDS``, tried in order: the first whose ``matches`` takes the path
checks it. YAML files are told apart by the one top-level key each kind must have.
"""

from __future__ import annotations

import copy
import functools
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError


@dataclass(frozen=True)
class Checked:
    """One file's verdict: its kind, a one-line summary when it is valid, else its problems."""

    name: str
    kind: str
    summary: str = ""
    problems: tuple[str, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_dict(self) -> dict[str, Any]:
        return {
            "file": self.name,
            "kind": self.kind,
            "ok": self.ok,
            "summary": self.summary,
            "problems": list(self.problems),
        }


_FIELD = re.compile(r"^[A-Za-z0-9_.\-]+$")


class Lint:
    """One file's problems as they are found, each a line ``SOURCE[:LINE]: field: message``;
    the line is looked up in the YAML's node tree by the field's path (``prefix``: where a
    part of the file sits, ``run.`` for a gate file's matrix)."""

    def __init__(self, source: str, text: str | None = None) -> None:
        self.source = source
        self.problems: list[str] = []
        self._root = None
        if text is not None:
            import yaml

            try:
                self._root = yaml.compose(text, Loader=yaml.SafeLoader)
            except yaml.YAMLError:
                self._root = None  # read_yaml named the problem already

    def add(self, message: str, prefix: str = "") -> None:
        for line in message.splitlines():
            if line.strip():
                self.problems.append(self._located(line.strip(), prefix))

    def attempt(self, check: Callable[[], Any], prefix: str = "") -> Any:
        """``check()``'s value, or None with its InputError's lines added."""
        try:
            return check()
        except InputError as exc:
            self.add(str(exc), prefix)
            return None

    def _located(self, line: str, prefix: str) -> str:
        head = f"{self.source}: "
        if not line.startswith(head):
            return line  # names another file (a suite a spec reads), or its own place
        rest = line[len(head) :]
        name, sep, message = rest.partition(": ")
        if not sep or not _FIELD.match(name):
            return line
        name = prefix + name
        number = self.line_of(name.split("."))
        where = f"{self.source}:{number}" if number else self.source
        return f"{where}: {name}: {message}"

    def line_of(self, parts: list[str]) -> int | None:
        """The 1-based line of the deepest node of ``parts`` the YAML has (a key's own line);
        a key may hold dots itself (the budget ``ate_rmse_m.mean``): the longest one wins."""
        import yaml

        node, line, i = self._root, None, 0
        while i < len(parts):
            if isinstance(node, yaml.MappingNode):
                keys = {str(k.value): (k, v) for k, v in node.value}
                j = next((j for j in range(len(parts), i, -1) if ".".join(parts[i:j]) in keys), None)
                if j is None:
                    break
                key, node = keys[".".join(parts[i:j])]
                line, i = key.start_mark.line + 1, j
            elif (
                isinstance(node, yaml.SequenceNode) and parts[i].isdigit() and int(parts[i]) < len(node.value)
            ):
                node = node.value[int(parts[i])]
                line, i = node.start_mark.line + 1, i + 1
            else:
                break
        return line


_PLURALS = {"strategy": "strategies", "sequence entry": "sequence entries", "family": "families"}


def _plural(count: int, word: str) -> str:
    return f"{count} {word if count == 1 else _PLURALS.get(word, word + 's')}"


# ---- YAML kinds ---------------------------------------------------------------------------


def _scenario(path: Path, lint: Lint) -> str:
    from depotbench.scenes.resolve import scenario_model

    scenario = lint.attempt(lambda: scenario_model(path))
    if scenario is None:
        return ""
    return (
        f"'{scenario.name}', {scenario.n_frames} frames, {sum(a.count for a in scenario.actors)} actors, "
        f"camera {scenario.camera.motion}"
    )


def _suite(path: Path, lint: Lint) -> str:
    from depotbench.scenes.suite import load_suite, variations

    suite = lint.attempt(lambda: load_suite(path))
    jobs = None if suite is None else lint.attempt(lambda: variations(suite, path))
    if jobs is None:
        return ""
    return f"{len(jobs)} sequences, {sum(sc.n_frames for _, _, sc in jobs)} frames in all"


def _benchmark(path: Path, lint: Lint) -> str:
    from depotbench.eval.benchmark.sequences import check_specs
    from depotbench.eval.benchmark.spec import load_benchmark

    benchmark = lint.attempt(lambda: load_benchmark(path))
    if benchmark is None or lint.attempt(lambda: check_specs(benchmark) or True) is None:
        return ""
    frozen = sum(s.files_key is not None for s in benchmark.sequences)
    return (
        f"'{benchmark.name}', {_plural(len(benchmark.spec.scenarios), 'scenario')}, "
        f"{_plural(len(benchmark.sequences), 'sequence')} ({frozen} frozen), "
        f"{sum(s.frames for s in benchmark.sequences)} frames"
    )


def _matrix(spec: Any, path: Path, lint: Lint, prefix: str = "") -> str:
    """Every semantic check of a sweep's matrix, each adding its own lines; its size when all hold."""
    from depotbench.eval.sweep import engine
    from depotbench.eval.sweep import spec as sweep_spec
    from depotbench.slam.config import setting_names

    source = str(path)
    before = len(lint.problems)
    for line in sweep_spec.unknown_thresholds(spec, source):
        lint.add(line, prefix)
    known = setting_names()
    kept = {s: {n: a for n, a in axes.items() if n in known} for s, axes in spec.thresholds.items()}
    spec = spec.model_copy(update={"thresholds": kept})
    trackers = lint.attempt(lambda: sweep_spec.tracker_configs(spec, source), prefix)
    detectors = lint.attempt(lambda: sweep_spec.detector_configs(spec, source), prefix)
    if trackers is not None:
        found = sweep_spec.variants(spec) if sweep_spec.variant_count(spec) <= sweep_spec.MAX_JOBS else None
        if found is None:
            lint.add(
                f"{source}: thresholds: {sweep_spec.variant_count(spec)} variants exceed the limit of "
                f"{sweep_spec.MAX_JOBS}",
                prefix,
            )
        else:
            lint.attempt(lambda: sweep_spec.check_variants(spec, found, trackers, source), prefix)
            lint.attempt(lambda: sweep_spec.tracker_variants(spec, trackers, source), prefix)
            lint.attempt(lambda: sweep_spec.check_search(spec, trackers, source), prefix)
    sequences, first = 0, None
    for i, name in enumerate(spec.sequences):  # each entry on its own: one missing folder hides no other
        one = spec.model_copy(update={"sequences": [name]})
        try:
            entries = engine.named_sequences(one, path)
        except InputError as exc:
            said = str(exc).replace(f"{source}: sequences.0:", f"{source}: sequences.{i}:", 1)
            lint.add(said if said.startswith(source) else f"{source}: sequences.{i}: {said}", prefix)
            continue
        sequences += len(entries)
        first = first or (entries[0].root if entries else None)
    if first is not None and trackers is not None:
        _templates(trackers, first, source, lint, prefix)
    if spec.suite is not None:
        from depotbench.scenes.suite import load_suite, variations

        suite_path = lint.attempt(lambda: engine.suite_file(spec, path), prefix)
        suite = None if suite_path is None else lint.attempt(lambda: load_suite(suite_path))
        jobs = None if suite is None else lint.attempt(lambda: variations(suite, suite_path))
        sequences += len(jobs or ())
    if len(lint.problems) > before or trackers is None or detectors is None:
        return ""
    per_tracker = [_runs_per_sequence(spec, t) for t in sweep_spec.tracker_variants(spec, trackers, source)]
    runs = sequences * len(detectors) * sum(per_tracker)
    variants = sweep_spec.variant_count(spec)
    shape = (
        f"{_plural(sequences, 'sequence')} x {_plural(len(per_tracker), 'tracker')} x "
        f"{_plural(len(detectors), 'detector')} x {_plural(variants, 'variant')} = {_plural(runs, 'run')}"
    )
    if runs != sequences * len(per_tracker) * len(detectors) * variants:
        shape += " (an external tracker runs only the none and mask variants)"
    if spec.search is not None:  # each trial runs every sequence once, after the grid
        shape += f", then {_plural(spec.search.trials, 'search trial')} of {_plural(sequences, 'run')} each"
    if runs == 0:
        lint.add(f"{source}: sequences: the matrix is empty ({shape}); nothing would run", prefix)
    return shape


def _templates(trackers: list, root: Path, source: str, lint: Lint, prefix: str) -> None:
    """Each tracker's settings template rendered on a real camera (the first sequence's), as
    ``sweep`` renders it before a run: a template that cannot render is refused here."""
    from depotbench.eval.trackers.registry import check as check_tracker
    from depotbench.sim.sequence import Sequence

    opened = Sequence.open(root)  # opened once already by named_sequences
    for i, tracker in enumerate(trackers):
        if tracker.settings_template is not None:
            try:
                check_tracker(tracker, opened)
            except InputError as exc:
                lint.add(f"{source}: trackers.{i}: {tracker.label}: {exc}", prefix)


def _runs_per_sequence(spec: Any, tracker: Any) -> int:
    """The variants one tracker runs (an external one: none and mask only), as ``jobs_for``."""
    from depotbench.eval.run.harness import EXTERNAL_STRATEGIES
    from depotbench.eval.sweep.spec import variants

    if tracker.type.per_keypoint:
        from depotbench.eval.sweep.spec import variant_count

        return variant_count(spec)
    return sum(1 for v in variants(spec) if v.strategy in EXTERNAL_STRATEGIES)


def _model(
    model: type, path: Path, data: Any, lint: Lint, drop: Callable[[str], bool] = lambda _: False
) -> Any:
    from depotbench.scenes.schema import validate_model

    try:
        return validate_model(model, data, str(path))
    except InputError as exc:
        for line in str(exc).splitlines():
            if not drop(line):
                lint.add(line)
        return None


def _sweep(path: Path, lint: Lint) -> str:
    from depotbench.eval.sweep.spec import SweepSpec

    spec = _model(SweepSpec, path, _read_yaml(path), lint)
    if spec is None:
        return ""
    shape = _matrix(spec, path, lint)
    source = f"suite {spec.suite}" if spec.suite else f"{_plural(len(spec.sequences), 'sequence entry')}"
    return f"'{spec.sweep}', {_plural(len(spec.strategies), 'strategy')} over {source}: {shape}"


_BUDGET_LINE = re.compile(r": checks\.\d+: budgets\.")


def _gates(path: Path, lint: Lint) -> str:
    from depotbench.eval.gates.budgets import GateFile, budget_problem

    data = _read_yaml(path)
    for i, check in enumerate(data.get("checks") or []):  # every budget, not the first of a check
        budgets = check.get("budgets") if isinstance(check, dict) else None
        for name, bound in (budgets or {}).items() if isinstance(budgets, dict) else ():
            if not isinstance(bound, dict):
                continue
            low, high = bound.get("min"), bound.get("max")
            numbers = all(v is None or type(v) in (int, float) for v in (low, high))
            problem = budget_problem(str(name), low, high) if numbers else None
            if problem is not None:
                lint.add(f"{path}: checks.{i}.budgets.{name}: {problem}")
    gates = _model(GateFile, path, data, lint, drop=lambda line: bool(_BUDGET_LINE.search(line)))
    if gates is None:
        _run_alone(path, data, lint)
        return ""
    shape = _matrix(gates.run, path, lint, prefix="run.")
    budgets = sum(len(c.budgets) for c in gates.checks)
    return f"'{gates.gates}', {_plural(len(gates.checks), 'check')}, {_plural(budgets, 'budget')}: {shape}"


def _run_alone(path: Path, data: dict, lint: Lint) -> None:
    """A gate file refused elsewhere (its checks) still has its matrix checked, where the
    matrix itself is a valid sweep: all of a file's problems in one pass."""
    from depotbench.eval.sweep.spec import SweepSpec
    from depotbench.scenes.schema import validate_model

    run = data.get("run")
    if not isinstance(run, dict) or any(": run" in line for line in lint.problems):
        return
    try:
        spec = validate_model(SweepSpec, {"sweep": str(data.get("gates", "gates")), **run}, str(path))
    except InputError:
        return
    _matrix(spec, path, lint, prefix="run.")


# ---- other files --------------------------------------------------------------------------


def _camera(path: Path, lint: Lint) -> str:
    from depotbench.sim.camera import read_camera_file

    camera = lint.attempt(lambda: read_camera_file(path))
    if camera is None:
        return ""
    fx, fy, cx, cy = camera.pinhole or (0.0, 0.0, 0.0, 0.0)
    size = f"{camera.size[0]}x{camera.size[1]}, " if camera.size else ""
    return (
        f"ORB-SLAM settings, {size}fx {fx:g} fy {fy:g} cx {cx:g} cy {cy:g}, "
        f"depth factor {camera.depth_factor:g}"
    )


def _trajectory(path: Path, lint: Lint) -> str:
    from depotbench.eval.metrics.trajectory import read_tum

    trajectory = lint.attempt(lambda: read_tum(path))
    if trajectory is None:
        return ""
    times = trajectory.timestamps_s
    span = float(times[-1] - times[0]) if len(times) else 0.0
    return f"TUM trajectory, {_plural(len(times), 'pose')} over {span:.1f} s"


def _sequence(path: Path, lint: Lint) -> str:
    from depotbench.sim.sequence import Sequence

    sequence = lint.attempt(lambda: Sequence.open(path))
    if sequence is None:
        return ""
    k = sequence.intrinsics
    truth = "exact ground truth" if (path / "gt" / "objects.jsonl").is_file() else "no object ground truth"
    return f"{_plural(len(sequence.frames), 'frame')}, {k.width}x{k.height}, {truth}"


def _results(path: Path, lint: Lint) -> str:
    from depotbench.eval.sweep.engine import DATABASE
    from depotbench.eval.sweep.store import ResultStore

    database = path / DATABASE if path.is_dir() else path

    def rows() -> list:
        with ResultStore(database, readonly=True) as store:
            return store.rows()

    found = lint.attempt(rows)
    if found is None:
        return ""
    failed = sum(1 for row in found if row.get("failure"))
    families = len({row.get("family") for row in found})
    return f"{_plural(len(found), 'run')} ({failed} failed) over {_plural(families, 'family')}"


def _suite_folder(path: Path, lint: Lint) -> str:
    from depotbench.eval.sweep.engine import _folder_entries

    entries = lint.attempt(lambda: _folder_entries(path, str(path)))
    return "" if entries is None else f"{_plural(len(entries), 'sequence')}, each complete"


def _head(path: Path) -> bytes:
    """The first bytes of a regular file (a FIFO or device is never opened: it could block)."""
    if not path.is_file():
        return b""
    try:
        with path.open("rb") as handle:
            return handle.read(16)
    except OSError:
        return b""


@functools.lru_cache(maxsize=4)
def _parsed(path: str, mtime_ns: int, size: int) -> tuple[Any, InputError | None]:
    from depotbench.scenes.schema import read_yaml

    try:
        return read_yaml(Path(path)), None
    except InputError as exc:
        return None, exc


def _read_yaml(path: Path) -> Any:
    """``read_yaml`` once per version of a file: finding a file's kind and checking it ask for
    it six times, and a hostile file costs each time (5000 nested brackets: 1.9 s a parse)."""
    from depotbench.scenes.schema import read_yaml

    try:
        stat = path.stat()
    except OSError:
        return read_yaml(path)  # names the problem
    data, problem = _parsed(str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    if problem is not None:
        raise problem
    return copy.deepcopy(data)  # a caller's changes stay its own


def _yaml_kind(key: str) -> Callable[[Path], bool]:
    def matches(path: Path) -> bool:
        try:
            return key in _read_yaml(path)
        except InputError:
            return False

    return matches


def _is_suite_folder(path: Path) -> bool:
    from depotbench.core.output import OutputKind, read_marker

    marker = read_marker(path) if path.is_dir() else None
    return marker is not None and marker.kind is OutputKind.SUITE


@dataclass(frozen=True)
class Kind:
    matches: Callable[[Path], bool]
    """Whether a path is of this kind (from what it holds, never from its name alone)."""
    check: Callable[[Path, Lint], str]
    """Its problems added to the lint; the one-line summary when there are none."""


KINDS: dict[str, Kind] = {
    "results": Kind(
        lambda p: (
            (p.is_dir() and (p / "results.sqlite").is_file()) or _head(p).startswith(b"SQLite format 3")
        ),
        _results,
    ),
    "suite folder": Kind(_is_suite_folder, _suite_folder),
    "sequence folder": Kind(lambda p: p.is_dir() and (p / "rgb.txt").is_file(), _sequence),
    "camera file": Kind(lambda p: _head(p).startswith(b"%YAML:1.0"), _camera),
    "trajectory": Kind(lambda p: p.suffix == ".txt" and p.is_file(), _trajectory),
    "gate file": Kind(_yaml_kind("gates"), _gates),
    "sweep spec": Kind(_yaml_kind("sweep"), _sweep),
    "suite": Kind(_yaml_kind("suite"), _suite),
    "benchmark": Kind(_yaml_kind("benchmark"), _benchmark),
}
SCENARIO = "scenario"
"""A file of none of the kinds above, or a library scenario's name."""


def kind_of(path: Path) -> str:
    return next((name for name, kind in KINDS.items() if kind.matches(path)), SCENARIO)


def _lint(source: str, path: Path) -> Lint:
    """A lint whose YAML lines come from ``path`` (none for a folder or a binary file)."""
    text = None
    if path.is_file() and not _head(path).startswith((b"SQLite", b"%YAML:1.0")):
        try:
            _read_yaml(path)  # bounded and checked before it is composed again for its lines
            text = path.read_text()
        except (InputError, OSError, UnicodeError):
            text = None
    return Lint(source, text)


def validate_file(name: str) -> Checked:
    """``name`` (a file or folder, a shipped example's name or a library scenario's name)
    checked; every problem found is a line of its problems."""
    from depotbench.core.examples import Kind as Shipped
    from depotbench.core.examples import examples

    path = Path(name)
    shipped = examples().get(name)
    if not path.exists() and shipped is not None and shipped.kind is not Shipped.TRACKER:
        path = shipped.path  # a shipped file by name; a path that exists wins
    if not path.exists():
        return _checked(name, SCENARIO, lambda lint: _scenario(name, lint), Lint(str(path)))  # type: ignore[arg-type]
    if path.is_dir() and not any(kind.matches(path) for kind in KINDS.values()):
        what = (
            "a directory that is no sequence folder (rgb.txt), suite folder or sweep folder (results.sqlite)"
        )
        return Checked(name, "directory", problems=(f"{path}: {what}",))
    kind = kind_of(path)
    check = KINDS[kind].check if kind in KINDS else _scenario
    return _checked(name, kind, lambda lint: check(path, lint), _lint(str(path), path))


def _checked(name: str, kind: str, run: Callable[[Lint], str], lint: Lint) -> Checked:
    try:
        summary = run(lint)
    except InputError as exc:  # the file cannot be read at all: that one problem
        lint.add(str(exc))
        summary = ""
    problems = tuple(dict.fromkeys(lint.problems))
    return Checked(name, kind, "" if problems else summary, problems)
