"""Cache keys and sweep row keys cover every input that can change a result.

A stale key gives a wrong result without a word (reliability probe D1: a sequence
whose depth was zeroed in place still reported "tracked 6/6" from the stage cache), so
the property is checked file kind by file kind of the sequence format: each edit, even
one that keeps the file's size and modification time, changes the key, and the next
run computes its stages again instead of reading them from the cache.
"""

from __future__ import annotations

import csv
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.run.cache import StageCache
from depotbench.eval.run.detections import sequence_fingerprint
from depotbench.eval.run.harness import RunJob, track
from depotbench.sim.sequence import Sequence

SPEC = (
    "name: keyed\nframes: 4\nimage: {width: 160, height: 120}\nintrinsics: {fx: 131.25}\n"
    "actors:\n  - {kind: person, speed_mps: 1.2}\ncamera: {motion: xyz}\nsensor: kinect\n"
)
"""Small, with every optional file of the format: gt/depth (a sensor model) and gt/flow."""


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("keyed")
    spec = root / "keyed.yaml"
    spec.write_text(SPEC)
    assert main(["generate", str(spec), "-o", str(root / "seq"), "--flow"]) == 0
    return root / "seq"


def _keep_stat(edit: Callable[[Path], None]) -> Callable[[Path], None]:
    """Run ``edit`` and put the file's modification time back, as a careless copy would."""

    def edited(path: Path) -> None:
        before = path.stat()
        edit(path)
        os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))

    return edited


def _bump_digit_after(anchor: str) -> Callable[[Path], None]:
    """Change the last digit of the first number after ``anchor``: same size, still valid."""

    def edit(path: Path) -> None:
        text = path.read_text()
        start = text.index(anchor) + len(anchor)
        match = re.compile(r"\d(?=[,\s\]}])").search(text, start)
        digit = int(match.group())
        text = text[: match.start()] + str(digit - 1 if digit == 9 else digit + 1) + text[match.end() :]
        path.write_text(text)

    return edit


def _comment_case(path: Path) -> None:
    """Swap the case of a letter in the first comment line: same size, same meaning."""
    lines = path.read_text().split("\n")
    i = next(k for k, line in enumerate(lines) if line.startswith("#") and re.search("[A-Za-z]", line))
    j = re.search("[A-Za-z]", lines[i]).start()
    lines[i] = lines[i][:j] + lines[i][j].swapcase() + lines[i][j + 1 :]
    path.write_text("\n".join(lines))


def _pixel(path: Path) -> None:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    image.flat[image.size // 2] ^= 1
    cv2.imwrite(str(path), image)


def _flow(path: Path) -> None:
    with np.load(path) as data:
        arrays = {name: data[name].copy() for name in data.files}
    arrays["flow"].flat[0] += 0.5
    np.savez(path, **arrays)


EDITS: dict[str, Callable[[Path], None]] = {
    "associations.txt": _bump_digit_after("rgb/1.000000.png "),  # a depth timestamp, +1 us
    "rgb.txt": _comment_case,
    "depth.txt": _comment_case,
    "groundtruth.txt": _bump_digit_after("\n1.000000 "),  # tx of the first pose, +1 nm
    "camera.yaml": _comment_case,
    "meta.json": _bump_digit_after('"camera_speed_mps_mean": '),
    "gt/objects.jsonl": _bump_digit_after('"position_m":['),
    "rgb/*.png": _pixel,
    "depth/*.png": _pixel,
    "gt/instances/*.png": _pixel,
    "gt/depth/*.png": _pixel,
    "gt/flow/*.npz": _flow,
}
"""One edit per file kind of the sequence format (docs/format.md); each keeps the sequence valid."""


def _kind(relative: Path) -> str:
    return (
        str(relative)
        if relative.parent == Path(".") or relative.suffix == ".jsonl"
        else (f"{relative.parent}/*{relative.suffix}")
    )


def test_every_file_kind_of_the_format_changes_the_key_and_the_stages_are_computed_again(
    generated: Path, tmp_path: Path
):
    seq = tmp_path / "seq"
    shutil.copytree(generated, seq)
    sequence = Sequence.open(seq)
    kinds = {_kind(p.relative_to(seq)) for p in sequence.files()}
    assert kinds == set(EDITS), "the sequence format has a file kind this test does not edit"
    cache = StageCache(tmp_path / "cache")
    job = RunJob(seq, "box_epipolar_flow")
    track(job, cache)
    key = sequence_fingerprint(sequence)
    for kind, edit in EDITS.items():
        path = sorted(seq.glob(kind))[1] if "*" in kind else seq / kind
        size = path.stat().st_size
        _keep_stat(edit)(path)
        if path.suffix in (".txt", ".yaml", ".json", ".jsonl"):
            assert path.stat().st_size == size  # size and mtime alone cannot tell
        sequence = Sequence.open(seq)
        new_key = sequence_fingerprint(sequence)
        assert new_key != key, f"editing {kind} left the key unchanged"
        key = new_key
        misses = cache.misses
        track(job, cache)
        assert cache.misses == misses + 3, f"after editing {kind}, a stage came from the cache"


def test_another_version_computes_a_real_folders_stages_again(generated: Path, tmp_path: Path, monkeypatch):
    """A version's stages are its own (0.5.3 found other keypoints than 0.5.2 on 2-3 % of a
    frame). A generated sequence's meta.json names the version that made it, a real folder's
    files name none: its features and detections cached by an older version were reused after
    an upgrade."""
    from depotbench.core import version
    from depotbench.detectors.config import parse_detector
    from depotbench.eval.run import detections, stages

    seq = tmp_path / "real"
    shutil.copytree(generated, seq)
    (seq / "meta.json").unlink()
    shutil.rmtree(seq / "gt")
    assert not Sequence.open(seq).is_generated
    cache = StageCache(tmp_path / "cache")
    job = RunJob(seq, "box_rule", parse_detector("onnx"))
    folders = [tmp_path / "cache" / name for name in (stages.FEATURES_STAGE, detections.CACHE_STAGE)]
    track(job, cache)
    entries = [set(folder.iterdir()) for folder in folders]
    track(job, cache)
    assert [set(folder.iterdir()) for folder in folders] == entries  # the same version: reused
    monkeypatch.setattr(version.metadata, "version", lambda _: "0.0.0-another")  # an upgrade
    version.package_version.cache_clear()  # as a new process after it reads it
    try:
        track(job, cache)
    finally:
        monkeypatch.undo()
        version.package_version.cache_clear()
    assert [len(set(folder.iterdir()) - before) for folder, before in zip(folders, entries, strict=True)] == [
        1,
        1,
    ]


def test_an_edited_checkout_is_another_program_under_the_same_version(
    generated: Path, tmp_path: Path, monkeypatch
):
    """A source checkout's code changes under one version number, so its stage and run keys
    and the built-in's fingerprint follow its files (``code_version``): a stage or row cached
    before an edit is not served after it. Before, they hashed the version alone, and a run on
    the virtual-clock mapper cached before its cost model was fitted again under 0.8.0 kept
    the old model's result."""
    from depotbench.core import version
    from depotbench.eval.run import detections, stages
    from depotbench.eval.run.harness import job_key, tracker_fingerprint, tracker_identity

    cache = StageCache(tmp_path / "cache")
    job = RunJob(generated, "box_rule")
    folders = [tmp_path / "cache" / name for name in (stages.FEATURES_STAGE, detections.CACHE_STAGE)]

    def identity() -> tuple[str, str]:
        tracker = tracker_identity(job.tracker)
        key = job_key(sequence_fingerprint(Sequence.open(generated)), tracker, job.detector, "box_rule", [])
        return key, tracker_fingerprint(tracker)

    assert version.code_version().startswith(version.package_version() + "+src.")  # tests run from a checkout
    track(job, cache)
    entries = [set(folder.iterdir()) for folder in folders]
    first = identity()
    monkeypatch.setattr(version, "source_digest", lambda: "0123456789ab")  # an edit, the same version
    track(job, cache)
    added = [len(set(folder.iterdir()) - before) for folder, before in zip(folders, entries, strict=True)]
    assert added == [1, 1]  # features and detections computed again
    second = identity()
    assert first[0] != second[0] and first[1] != second[1]


def test_a_checkouts_digest_follows_its_files_not_their_bytecode(tmp_path: Path, monkeypatch):
    """``source_digest`` hashes every file's name and bytes under the package folders,
    ``__pycache__`` aside; an installed release (no checkout) keys by its version alone."""
    from depotbench.core import version

    root = tmp_path / "slam"
    root.mkdir()
    (root / "tracking.py").write_text("KEYFRAMES = 1\n")
    monkeypatch.setattr(version, "source_roots", lambda: [root])
    monkeypatch.setattr(version, "_editable", lambda: True)

    def digest() -> str | None:
        version.source_digest.cache_clear()  # as a new process
        return version.source_digest()

    try:
        first = digest()
        (root / "__pycache__").mkdir()
        (root / "__pycache__" / "tracking.cpython-311.pyc").write_bytes(b"\0")
        assert digest() == first
        (root / "tracking.py").write_text("KEYFRAMES = 2\n")
        second = digest()
        (root / "settings.yaml").write_text("a: 1\n")
        third = digest()
        (root / "settings.yaml").rename(root / "other.yaml")
        assert len({first, second, third, digest()}) == 4
        monkeypatch.setattr(version, "_editable", lambda: False)
        assert digest() is None and version.code_version() == version.package_version()
    finally:
        version.source_digest.cache_clear()


def test_only_a_package_beside_its_pyproject_is_a_checkout(tmp_path: Path, monkeypatch):
    from importlib.machinery import ModuleSpec

    from depotbench.core import version

    assert version._editable()  # this checkout
    site = tmp_path / "site-packages" / "depotbench"
    site.mkdir(parents=True)
    (site / "__init__.py").write_text("")
    installed = ModuleSpec("depotbench", None, origin=str(site / "__init__.py"))
    monkeypatch.setattr(version.util, "find_spec", lambda name: installed)
    assert not version._editable()
    (tmp_path / "site-packages" / "pyproject.toml").write_text("")
    assert version._editable()


def test_the_folder_is_no_part_of_the_key_but_the_camera_it_is_read_with_is(generated: Path, tmp_path: Path):
    """A copy, a move or a new name is the same sequence (issue 50: its rows are resumed and
    paired with a baseline made elsewhere); a real folder's camera, guessed from its name
    where it has no camera.yaml, is hashed as the camera it gave."""
    shutil.copytree(generated, tmp_path / "a")
    shutil.copytree(generated, tmp_path / "b")  # the same bytes and times, elsewhere
    a, b = (sequence_fingerprint(Sequence.open(tmp_path / name)) for name in "ab")
    assert a == b == sequence_fingerprint(Sequence.open(generated))
    fr1, fr3 = (_real_folder(tmp_path / name) for name in ("rgbd_freiburg1_x", "rgbd_freiburg3_x"))
    assert len({a, fr1, fr3}) == 3


def _real_folder(root: Path) -> str:
    """A one-frame 640x480 TUM folder with no camera.yaml (its camera is guessed from its name)."""
    for kind, image in (
        ("rgb", np.zeros((480, 640, 3), np.uint8)),
        ("depth", np.full((480, 640), 5000, np.uint16)),
    ):
        (root / kind).mkdir(parents=True)
        cv2.imwrite(str(root / kind / "1.000000.png"), image)
        (root / f"{kind}.txt").write_text(f"1.000000 {kind}/1.000000.png\n")
    (root / "groundtruth.txt").write_text("1.000000 0 0 0 0 0 0 1\n")
    return sequence_fingerprint(Sequence.open(root))


def test_a_sweep_naming_one_sequence_twice_is_refused_naming_both(generated: Path, tmp_path: Path, capsys):
    """Probe N5: a suite and one of its sequences, or a folder and its copy, were one job with
    one key: one row labelled twice, a family gone from the summary, "3 rows" for 2."""
    shutil.copytree(generated, tmp_path / "a")
    shutil.copytree(generated, tmp_path / "b")
    spec = tmp_path / "twice.yaml"
    spec.write_text("sweep: twice\nsequences: [a, b]\nstrategies: [none]\n")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds the same sequence as" in err[0] and str(tmp_path / "a") in err[0], err
    assert not (tmp_path / "sw" / "results.csv").exists()


def _zero_depth(seq: Path) -> None:
    for path in (seq / "depth").glob("*.png"):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(path), np.zeros_like(image))


def _tracked(capsys) -> str:
    return re.search(r"tracked \d+/\d+", capsys.readouterr().out).group()


def test_a_run_after_its_depth_was_zeroed_in_place_is_the_run_without_the_cache(
    generated: Path, tmp_path: Path, capsys, monkeypatch
):
    """Probe D1 `stale-depth-cached`: it reported the old "tracked 6/6" from the cache."""
    monkeypatch.setenv("DEPOTBENCH_CACHE", str(tmp_path / "cache"))
    seq = tmp_path / "seq"
    shutil.copytree(generated, seq)
    assert main(["run", str(seq), "-o", str(tmp_path / "a"), "--strategy", "box_epipolar_flow"]) == 0
    assert _tracked(capsys) == "tracked 4/4"
    _zero_depth(seq)
    assert main(["run", str(seq), "-o", str(tmp_path / "b"), "--strategy", "box_epipolar_flow"]) == 0
    cached = _tracked(capsys)
    monkeypatch.setenv("DEPOTBENCH_CACHE", "off")
    assert main(["run", str(seq), "-o", str(tmp_path / "c"), "--strategy", "box_epipolar_flow"]) == 0
    assert cached == _tracked(capsys) == "tracked 0/4"


def _rows(sweep: Path) -> list[dict[str, str]]:
    with (sweep / "results.csv").open() as handle:
        return list(csv.DictReader(handle))


def test_a_sweep_over_a_folder_and_its_altered_copy_keeps_a_row_for_each(generated: Path, tmp_path: Path):
    """Probe D1 `sweep-two-copies`: one row, labelled with the copy, holding the original's result."""
    shutil.copytree(generated, tmp_path / "a")
    shutil.copytree(generated, tmp_path / "b")
    _zero_depth(tmp_path / "b")
    spec = tmp_path / "two.yaml"
    spec.write_text("sweep: two\nsequences: [a, b]\nstrategies: [none]\n")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    rows = {Path(r["sequence"]).name: r for r in _rows(tmp_path / "sw")}
    assert sorted(rows) == ["a", "b"]
    assert float(rows["a"]["tracked_fraction"]) == 1.0
    assert float(rows["b"]["tracked_fraction"]) == 0.0


@pytest.mark.slow  # 9 s; altered copies keep their own rows in the default run (the test above)
def test_a_resumed_sweep_scores_a_corrected_ground_truth_again(generated: Path, tmp_path: Path):
    """Probe D1 `tum-sweep-2-after-gt-change`: "1 already done", with the old ATE."""
    tum = tmp_path / "tum"
    shutil.copytree(generated, tum)
    for name in ("meta.json", ".depotbench.json"):
        (tum / name).unlink()
    shutil.rmtree(tum / "gt")
    spec = tmp_path / "tum.yaml"
    spec.write_text("sweep: tum\nsequences: [tum]\ndetectors: [none]\nstrategies: [none]\n")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    gt = tum / "groundtruth.txt"
    lines = gt.read_text().splitlines()
    scaled = [line if line.startswith("#") else _scale_position(line, 3.0) for line in lines]
    gt.write_text("\n".join(scaled) + "\n")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    assert main(["sweep", str(spec), "-o", str(tmp_path / "fresh")]) == 0
    resumed, fresh = _rows(tmp_path / "sw"), _rows(tmp_path / "fresh")
    assert [r["ate_rmse_m"] for r in resumed] == [r["ate_rmse_m"] for r in fresh]


def _scale_position(line: str, factor: float) -> str:
    fields = line.split()
    fields[1:4] = [f"{float(v) * factor:.9f}" for v in fields[1:4]]
    return " ".join(fields)


def test_a_run_of_an_external_program_is_keyed_by_the_program_and_vocabulary_bytes(tmp_path: Path):
    """A rebuilt program or another vocabulary under the same path is a new run, not a row
    to resume."""
    from depotbench.eval.run.harness import tracker_identity
    from depotbench.eval.trackers.registry import TrackerConfig

    program, vocabulary = tmp_path / "my_slam.sh", tmp_path / "voc.txt"
    program.write_text("#!/bin/sh\nexit 0\n")
    program.chmod(0o755)
    vocabulary.write_text("10 6 0 0\n")
    tracker = TrackerConfig("cmd", f"{program} {{sequence}}", vocabulary)
    first = tracker_identity(tracker)
    assert tracker_identity(tracker) == first
    program.write_text("#!/bin/sh\nexit 1\n")
    second = tracker_identity(tracker)
    vocabulary.write_text("10 6 0 1\n")
    assert len({first, second, tracker_identity(tracker)}) == 3
    from depotbench.core.version import code_version

    assert tracker_identity(TrackerConfig()) == (("kind", "builtin"), ("version", code_version()))


def test_a_detector_is_keyed_by_the_bytes_of_its_class_names_file(tmp_path: Path):
    """`names=FILE` renames classes: an edited file under the same path is another detector,
    whose cached boxes and sweep rows are not the old ones."""
    from depotbench.detectors.config import parse_detector

    names = tmp_path / "names.txt"
    names.write_text("person\ndog\n")
    first = parse_detector("onnx", {"names": str(names)}).key()
    names.write_text("dog\nperson\n")
    assert parse_detector("onnx", {"names": str(names)}).key() != first


def test_an_opened_sequence_is_hashed_once_and_a_reopened_one_again(generated: Path, monkeypatch):
    """A branching sweep task keys features, stages and detections on one opened sequence: its
    files are read once. Opening the folder again reads them again (an edit shows)."""
    from depotbench.eval.run import detections

    reads = []
    real = detections.file_digest
    monkeypatch.setattr(detections, "file_digest", lambda path, what: reads.append(path) or real(path, what))
    sequence = Sequence.open(generated)
    first = sequence_fingerprint(sequence)
    n_files = len(reads)
    assert n_files == len(sequence.files()) > 10
    assert sequence_fingerprint(sequence) == first and len(reads) == n_files
    assert sequence_fingerprint(Sequence.open(generated)) == first and len(reads) == 2 * n_files


def test_a_moved_sequence_resumes_its_rows_which_then_name_its_new_folder(
    generated: Path, tmp_path: Path, capsys
):
    """Its key is its content: the second sweep runs nothing, and its rows (results.csv, the
    report's source) name the folder the sequence is in now, not the one it left."""
    shutil.copytree(generated, tmp_path / "old")
    spec = tmp_path / "moved.yaml"
    spec.write_text("sweep: moved\nsequences: [old]\nstrategies: [none]\n")
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    shutil.move(tmp_path / "old", tmp_path / "new")
    spec.write_text("sweep: moved\nsequences: [new]\nstrategies: [none]\n")
    capsys.readouterr()
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw")]) == 0
    assert "(1 already done" in capsys.readouterr().out
    assert [Path(row["sequence"]).name for row in _rows(tmp_path / "sw")] == ["new"]


def test_a_release_that_leaves_the_generator_alone_keeps_every_sequence_and_lock(
    generated: Path, tmp_path: Path, monkeypatch
):
    """The package's version keys runs and stages; the generator's (``GENERATOR_VERSION``) keys
    sequences and the benchmarks' locks. Before they were told apart, a release that changed
    only the tracker gave every sequence another spec key and meta.json, and every frozen
    benchmark (tum-dyn-1's 70 sequences) refused to run until frozen again."""
    from depotbench.core import version
    from depotbench.eval.benchmark.sequences import check_specs
    from depotbench.eval.benchmark.spec import load_benchmark
    from depotbench.eval.run import harness
    from depotbench.sim.spec import content_key, spec_from_dict

    spec = spec_from_dict(Sequence.open(generated).meta["scenario"])
    before = (content_key(spec), sequence_fingerprint(Sequence.open(generated)))
    detector = RunJob(generated, "none").detector

    def run_key() -> str:
        return harness.job_key(before[1], (("kind", "builtin"),), detector, "none", [])

    first_run = run_key()
    monkeypatch.setattr(version.metadata, "version", lambda _: "99.0.0")  # a later release
    version.package_version.cache_clear()
    try:
        assert version.package_version() == "99.0.0"
        assert version.generator_version() == version.GENERATOR_VERSION
        spec_file = tmp_path / "keyed.yaml"
        spec_file.write_text(SPEC)
        assert main(["generate", str(spec_file), "-o", str(tmp_path / "again"), "--flow"]) == 0
        again = Sequence.open(tmp_path / "again")
        assert (content_key(spec), sequence_fingerprint(again)) == before  # meta.json too
        assert again.meta["generator"] == f"depotbench {version.GENERATOR_VERSION}"
        check_specs(load_benchmark("smoke-1"))  # the shipped lock still holds for this release
        assert run_key() != first_run  # a run is the package's: another release, another row
    finally:
        monkeypatch.undo()
        version.package_version.cache_clear()
