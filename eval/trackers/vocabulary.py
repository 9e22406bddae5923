"""ORB vocabularies in DBoW2's text format (ORB-SLAM's ORBvoc.txt), built from generated frames.

ORB-SLAM2/3 need a bag-of-words vocabulary and the official ORBvoc.txt cannot be
downloaded here, so the bench builds its own, as DBoW2 builds one: ORB descriptors
of training images, hierarchical k-majority clustering (k-means on binary
descriptors: Hamming distance, bitwise-majority centres, k-means++ seeding) to
``levels`` levels of ``branching`` children, and for each leaf (word) the inverse
document frequency ln(N / n_i) over the N training images.

The text format (DBoW2's ``saveToTextFile``, read by ``loadFromTextFile``): a header
``k L scoring weighting`` (0 0: L1 norm, TF-IDF), then one line per node after the
root, in id order, ``parent is_leaf d0 ... d31 weight``; a parent's id is lower than
its children's. No newline follows the last line (ORB-SLAM's reader would take it
for an empty node).

The default vocabulary is trained on library scenes the fidelity benchmark does
not evaluate, rendered with their own seed, and cached by content in the ``vocabulary``
folder of the cache root (``depotbench.core.cache_home``). With that cache switched off
(``DEPOTBENCH_CACHE=off``) it is refused, not built: building takes a minute, and built
in a temporary folder it would be built again by every process, each worker of a sweep
too; off means that nothing is written beside the outputs a command names.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import multiprocessing
import os
import re
import stat
import tempfile
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from depotbench.core.cache_home import Contents, cache_folder, switched_off_by
from depotbench.core.errors import InputError
from depotbench.core.output import OutputLock, write_text_atomic
from depotbench.core.progress import progress_bar
from depotbench.core.version import package_version

BUILDER_VERSION = 1
LOG = logging.getLogger(__name__)

TRAINING_SCENES = (
    "dog_and_cat_roaming",
    "pig_pen",
    "chair_pushing",
    "robot_aisle_patrol",
    "crowd",
    "sitting_halfsphere",
)
"""Depot scenes the fidelity benchmark does not evaluate (it runs the walking and sitting
analogs and static_depot), so no evaluated frame is in the vocabulary."""
KMEANS_ITERATIONS = 10
DESCRIPTOR_BYTES = 32


@dataclass(frozen=True)
class VocabularySpec:
    branching: int = 10
    levels: int = 5
    scenes: tuple[str, ...] = TRAINING_SCENES
    frames: int = 150
    seed: int = 101

    def __post_init__(self) -> None:
        # ORB-SLAM's loader refuses k > 20 and L outside 1..10 (DBoW2's limits).
        if not 2 <= self.branching <= 20:
            raise InputError(f"--branching must lie in 2..20, got {self.branching}")
        if not 1 <= self.levels <= 10:
            raise InputError(f"--levels must lie in 1..10, got {self.levels}")
        if self.branching ** (self.levels + 1) > 2 * 10**7:
            raise InputError(f"{self.branching}^{self.levels} words is too many to build here")
        if not 1 <= self.frames <= 100_000:
            raise InputError(f"--frames must lie in 1..100000, got {self.frames}")
        if not self.scenes:
            raise InputError("--scenes: name at least one library scene")

    def key(self) -> str:
        data = {**asdict(self), "builder": BUILDER_VERSION, "generator": package_version()}
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


@dataclass(eq=False)
class Vocabulary:
    branching: int
    levels: int
    parents: list[int] = field(default_factory=lambda: [-1])
    """Parent id of each node; node 0 is the root."""
    descriptors: list[np.ndarray] = field(default_factory=lambda: [np.zeros(DESCRIPTOR_BYTES, np.uint8)])
    leaf: list[bool] = field(default_factory=lambda: [False])
    weights: list[float] = field(default_factory=lambda: [0.0])

    @property
    def words(self) -> int:
        return sum(self.leaf)

    def add(self, parent: int, descriptor: np.ndarray, leaf: bool) -> int:
        self.parents.append(parent)
        self.descriptors.append(descriptor)
        self.leaf.append(leaf)
        self.weights.append(0.0)
        return len(self.parents) - 1

    def to_text(self) -> str:
        lines = [f"{self.branching} {self.levels} 0 0"]
        for node in range(1, len(self.parents)):
            values = " ".join(str(int(b)) for b in self.descriptors[node])
            lines.append(f"{self.parents[node]} {int(self.leaf[node])} {values} {self.weights[node]:.10g}")
        return "\n".join(lines)


def _distances(descriptors: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Hamming distances (n, k) between packed descriptors (n, 4) and centres (k, 4), as uint64."""
    return np.stack([np.bitwise_count(descriptors ^ c).sum(axis=1, dtype=np.int32) for c in centres], axis=1)


def _majority(descriptors: np.ndarray) -> np.ndarray:
    """The bitwise majority of packed descriptors (ties set the bit, as DBoW2's meanValue)."""
    bits = np.unpackbits(descriptors.view(np.uint8).reshape(len(descriptors), DESCRIPTOR_BYTES), axis=1)
    counts = bits.sum(axis=0, dtype=np.int64)
    centre = np.packbits(2 * counts >= len(descriptors))
    return centre.view(np.uint64)


def _centres(descriptors: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The majority centre of each label that has members, in label order, and the labels
    renumbered to index them."""
    kept = np.unique(labels)
    return np.stack([_majority(descriptors[labels == c]) for c in kept]), np.searchsorted(kept, labels)


def _compiled_centres(descriptors: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``_centres`` by the compiled kernel (``clustering.majority_centres``)."""
    from depotbench.eval.trackers import clustering

    as_bytes = descriptors.view(np.uint8).reshape(len(descriptors), DESCRIPTOR_BYTES)
    centres, labels = clustering.majority_centres(as_bytes, labels, int(labels.max()) + 1)
    return centres.view(np.uint64), labels


def kmajority(descriptors: np.ndarray, k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """k-means on packed binary descriptors: (centres (k', 4), labels); k' <= k (no empty cluster).
    Compiled (``clustering``) or in NumPy by ``depotbench.slam.kernels``' switch: the same
    integers, so the same vocabulary."""
    from depotbench.slam import kernels

    distance, centres_of = _distances, _centres
    if kernels.compiled():
        from depotbench.eval.trackers import clustering

        distance, centres_of = clustering.distances, _compiled_centres
    n = len(descriptors)
    chosen = [int(rng.integers(n))]
    nearest = distance(descriptors, descriptors[chosen]).min(axis=1).astype(np.float64)
    while len(chosen) < k:  # k-means++ seeding, by distance
        total = nearest.sum()
        if total == 0:
            break  # fewer distinct descriptors than k
        pick = int(rng.choice(n, p=nearest / total))
        chosen.append(pick)
        nearest = np.minimum(nearest, distance(descriptors, descriptors[[pick]])[:, 0])
    centres = descriptors[chosen]
    labels = np.full(n, -1)
    for _ in range(KMEANS_ITERATIONS):
        new_labels = np.argmin(distance(descriptors, centres), axis=1)
        if np.array_equal(new_labels, labels):
            break
        centres, labels = centres_of(descriptors, new_labels)
    return centres, labels


def build(images: list[np.ndarray], branching: int, levels: int, seed: int = 0) -> Vocabulary:
    """The vocabulary of ORB descriptors grouped by training image ((m_i, 32) uint8 each)."""
    rng = np.random.default_rng(seed)
    if not images or not any(len(d) for d in images):
        raise InputError("no ORB descriptors to build a vocabulary from")
    packed = np.concatenate([np.ascontiguousarray(d, np.uint8) for d in images]).view(np.uint64)
    image_of = np.repeat(np.arange(len(images)), [len(d) for d in images])
    vocabulary = Vocabulary(branching, levels)
    word_of = np.full(len(packed), -1)
    pending: deque[tuple[int, np.ndarray, int]] = deque([(0, np.arange(len(packed)), 0)])
    while pending:  # breadth first: every parent is written before its children
        node, members, level = pending.popleft()
        subset = packed[members]
        distinct, inverse = np.unique(subset, axis=0, return_inverse=True)
        if len(distinct) <= branching:
            centres, labels = distinct, inverse.ravel()  # too few to cluster: each is a word
            final = True
        else:
            centres, labels = kmajority(subset, branching, rng)
            final = level + 1 >= levels
        for c, centre in enumerate(centres):
            child = vocabulary.add(node, centre.view(np.uint8), final)
            mine = members[labels == c]
            if final:
                word_of[mine] = child
            else:
                pending.append((child, mine, level + 1))
    n_images = len(images)
    # Each word's count of distinct training images, from the distinct (word, image) pairs:
    # one sort, where a comparison per word cost 100,000 passes over ~900,000 descriptors.
    pairs = np.unique(word_of.astype(np.int64) * n_images + image_of)
    words, images_with = np.unique(pairs // n_images, return_counts=True)
    for word, count in zip(words.tolist(), images_with.tolist(), strict=True):
        vocabulary.weights[word] = math.log(n_images / count)
    return vocabulary


def read_text(path: Path) -> Vocabulary:
    """A vocabulary written by ``to_text`` (for checks; ORB-SLAM reads the file itself)."""
    lines = path.read_text(encoding="utf-8").split("\n")
    k, levels, _, _ = (int(v) for v in lines[0].split())
    vocabulary = Vocabulary(k, levels)
    for line in lines[1:]:
        values = line.split()
        vocabulary.add(int(values[0]), np.array([int(v) for v in values[2:34]], np.uint8), values[1] == "1")
        vocabulary.weights[-1] = float(values[34])
    return vocabulary


def _scene_descriptors(name: str, frames: int, seed: int, progress: bool) -> list[np.ndarray]:
    """ORB descriptors (the built-in extractor's, which chooses as ORB-SLAM does) of every
    frame of one training scene, rendered into a temporary folder (a worker's entry point)."""
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate
    from depotbench.sim.sequence import Sequence
    from depotbench.slam.config import TrackingConfig
    from depotbench.slam.features import FeatureExtractor

    extractor = FeatureExtractor(TrackingConfig())
    images = []
    with tempfile.TemporaryDirectory(prefix="depotbench-vocab-") as scratch:
        scenario = library.get(name).model_copy(update={"frames": frames, "duration_s": None, "seed": seed})
        sequence = Sequence.open(generate(to_scenario(scenario), Path(scratch) / name, progress=progress))
        camera = sequence.intrinsics
        indices = progress_bar(
            range(len(sequence)), desc=f"ORB {name}", unit="frame", disable=not progress, leave=False
        )
        for i in indices:
            images.append(extractor.extract(sequence.rgb(i), sequence.depth_m(i), camera).descriptors)
    return images


def training_descriptors(spec: VocabularySpec, progress: bool, workers: int = 1) -> list[np.ndarray]:
    """ORB descriptors of every frame of the training scenes, in the scenes' order: each scene
    is rendered and extracted on its own, ``workers`` scenes at a time (the same bytes from
    any process: rendering and extraction are deterministic)."""
    from depotbench.core.executors import make_pool

    workers = max(1, min(workers, len(spec.scenes)))
    items = [(name, spec.frames, spec.seed, progress and workers == 1) for name in spec.scenes]
    slot = {id(item): i for i, item in enumerate(items)}  # a scene named twice is rendered twice
    per_scene: list[list[np.ndarray]] = [[] for _ in items]
    pool = make_pool("local", workers)
    failed = True
    # One process shows each scene's frames; workers show the scenes as they finish.
    bar = progress_bar(total=len(items), desc="scenes", unit="scene", disable=not progress or workers == 1)
    try:
        with bar:
            for item, images in pool.map_unordered(_scene_descriptors, items):
                per_scene[slot[id(item)]] = images
                bar.update(1)
        failed = False
    finally:
        pool.close(failed)
    return [image for images in per_scene for image in images]


def build_file(
    spec: VocabularySpec, path: Path, progress: bool, workers: int = 1
) -> tuple[Vocabulary, float]:
    """Build ``spec``'s vocabulary into ``path`` (atomically), its scenes rendered ``workers`` at a
    time; return it and the seconds taken."""
    started = time.perf_counter()
    if progress:
        LOG.info(f"rendering and extracting {len(spec.scenes)} scenes, {workers} at a time")
    images = training_descriptors(spec, progress, workers)
    if progress:
        LOG.info(f"clustering {sum(len(d) for d in images)} descriptors of {len(images)} frames")
    vocabulary = build(images, spec.branching, spec.levels, spec.seed)
    write_text_atomic(path, vocabulary.to_text())
    return vocabulary, time.perf_counter() - started


def build_workers() -> int:
    """How many processes render the training scenes: one per core in a command's own process,
    one inside a worker (a sweep's worker building the vocabulary must not start a pool)."""
    return max(1, os.cpu_count() or 1) if multiprocessing.parent_process() is None else 1


CACHE = "vocabulary"
"""The cache's name under the root (``depotbench.core.cache_home.CACHES``)."""
CACHED_NAME = re.compile(r"orb-k[0-9]+-L[0-9]+-[0-9a-f]{16}\.txt")
"""The name of a cached vocabulary (``cached_name``): only such files are ever cleared."""


def cached_name(spec: VocabularySpec) -> str:
    return f"orb-k{spec.branching}-L{spec.levels}-{spec.key()}.txt"


def cached_files(folder: Path) -> list[Path]:
    """The vocabularies in the cache folder ``folder`` (only files named as it names them)."""
    try:
        names = sorted(folder.iterdir())
    except FileNotFoundError:
        return []
    return [p for p in names if CACHED_NAME.fullmatch(p.name) and p.is_file() and not p.is_symlink()]


def clear_cached(folder: Path) -> Contents:
    """Remove the cached vocabularies; returns how many went and their bytes. A vocabulary
    is written whole or not at all (``write_text_atomic``), so a builder at work is not
    disturbed; a tracker that was handed a path an instant before it went cannot open it."""
    removed = freed = 0
    for path in cached_files(folder):
        try:
            size = path.stat().st_size
            path.unlink()
        except FileNotFoundError:
            continue  # removed by another process meanwhile
        removed += 1
        freed += size
    return Contents(removed, freed)


def vocabulary_problem(path: Path) -> str | None:
    """What keeps ``path`` from being a vocabulary file, or None: missing, a folder, or not a
    regular file. ORB-SLAM reads the file itself, so a device or a pipe would hang or fill
    memory there (/dev/zero never ends) instead of failing here."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return "no such vocabulary (build one with `depotbench vocab -o FILE`)"
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if stat.S_ISDIR(mode):
        return "is a folder, not a vocabulary file"
    if not stat.S_ISREG(mode):
        return "is not a regular file (a device, pipe or socket), not a vocabulary"
    return None


def default_vocabulary(
    progress: bool = True, spec: VocabularySpec | None = None, workers: int | None = None
) -> Path:
    """The cached vocabulary of ``spec`` (the default one), built first if missing, its scenes
    rendered ``workers`` at a time (default: ``build_workers``)."""
    spec = spec or VocabularySpec()
    folder = cache_folder(CACHE)
    if folder is None:
        raise InputError(
            f"{switched_off_by(CACHE)}: the ORB vocabulary cache is off, and building a vocabulary takes "
            "a minute or more: build one once with `depotbench vocab -o FILE` and pass --vocabulary FILE"
        )
    path = folder / cached_name(spec)
    if path.is_file():
        return path
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(
            f"{folder}: cannot keep the ORB vocabulary here ({exc.strerror or exc}); set "
            "DEPOTBENCH_CACHE_VOCABULARY (or DEPOTBENCH_CACHE) to a writable folder, or build one with "
            "`depotbench vocab -o FILE` and pass --vocabulary FILE"
        ) from None
    with OutputLock(path, wait=True):  # one builder at a time; the others then find it built
        if not path.is_file():
            if progress:
                LOG.info(f"building the ORB vocabulary once into {path} (about a minute)")
            build_file(spec, path, progress, build_workers() if workers is None else workers)
    return path
