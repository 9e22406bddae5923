"""Generated sequences as a detector training set: YOLO and COCO, split by sequence.

Frames of one sequence are near-duplicates, so a split by frame would leak the
validation set into training; the split is by sequence (seeded, or named). One
image folder serves both formats:

    images/{train,val}/<sequence>_<timestamp>.png   the RGB frames, bytes as generated
    labels/{train,val}/<same>.txt                   YOLO: class cx cy w h, normalised
    data.yaml                                       YOLO's dataset file (names in id order)
    annotations/instances_{train,val}.json          COCO: boxes [x, y, w, h], visible-pixel area
    splits.json                                     which sequence went where, and the counts

Boxes are the true visible boxes (``gt/objects.jsonl``); objects with fewer than
``min_visible_pixels`` visible pixels are left out.

Class ids are COCO's (``depotbench.detectors.coco``): in YOLO labels the index (person 0, the
desk as dining table 60, tv 62), in COCO json COCO's own category ids (person 1, dining table
67, tv 72: 1..90 with gaps), then the bench's classes COCO lacks (pig: 80 in YOLO, 91 in COCO
json). The same class has the same id in every export, whatever its scenes hold, and a
COCO-trained model's ids mean the same.
``data.yaml`` gives the folder's absolute ``path``: Ultralytics reads a relative one
against the working directory (or its datasets folder), not against the file.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from depotbench.core.errors import FileError, InputError
from depotbench.core.files import MAX_IMAGE_BYTES, dumps_json
from depotbench.core.output import OutputError, OutputKind, StagedOutput
from depotbench.core.progress import progress_bar
from depotbench.detectors.coco import EXPORT_CATEGORY_IDS, EXPORT_CLASSES, bench_name, export_name
from depotbench.sim.ground_truth import ObjectState
from depotbench.sim.sequence import Sequence, timestamp_name

PARTS = ("train", "val")


@dataclass(frozen=True)
class ClassTable:
    """The export's class numbering: names in id order (data.yaml's ``names``) and the id of
    each bench class that gets boxes."""

    names: tuple[str, ...]
    ids: tuple[tuple[str, int], ...]
    """(bench class, id) pairs; a class not listed gets no box."""
    appended: tuple[str, ...] = ()
    """Classes numbered after the fixed table (neither COCO's nor the bench's built-in ones,
    e.g. a kind registered at run time): their ids depend on what this export holds."""
    names_file: str | None = None
    """Where the numbering came from: a ``--names`` file, or None for COCO's."""
    category_ids: tuple[int, ...] = ()
    """COCO json's ``category_id`` of each of ``names``, in order: COCO's own ids for COCO's
    table (not the index + 1, which made the dog COCO's cat), line number for a names file."""

    @classmethod
    def coco(cls, present: set[str]) -> ClassTable:
        """COCO's 80 by their index, the bench's own classes after them (``EXPORT_CLASSES``),
        then any other class of ``present``, sorted."""
        index = {name: i for i, name in enumerate(EXPORT_CLASSES)}
        ids = {c: index[name] for c in present if (name := export_name(c)) is not None}
        appended = tuple(sorted(c for c in present if c not in ids))
        ids |= {c: len(EXPORT_CLASSES) + k for k, c in enumerate(appended)}
        after = max(EXPORT_CATEGORY_IDS) + 1
        category_ids = EXPORT_CATEGORY_IDS + tuple(range(after, after + len(appended)))
        return cls(EXPORT_CLASSES + appended, tuple(sorted(ids.items())), appended, None, category_ids)

    @classmethod
    def from_names(cls, names: list[str], shown: str) -> ClassTable:
        """A names file's numbering (one name a line, id = line order), each name read as the
        ONNX detector reads a model's table: 'dining table' and 'diningtable' are the desk."""
        if not names:
            raise InputError(f"{shown}: needs distinct class names, one a line")
        ids: dict[str, int] = {}
        for i, name in enumerate(names):
            bench = bench_name(name)
            if bench in ids:
                first = names[ids[bench]]
                same = "given twice" if first == name else f"the bench's {bench!r}, as {first!r} is"
                raise InputError(f"{shown}: needs distinct class names, one a line; {name!r} is {same}")
            ids[bench] = i
        category_ids = tuple(range(1, len(names) + 1))  # COCO json's ids start at 1
        return cls(tuple(names), tuple(sorted(ids.items())), names_file=shown, category_ids=category_ids)


@dataclass(frozen=True)
class ExportOptions:
    val_fraction: float = 0.2
    seed: int = 0
    val: tuple[str, ...] = ()
    """Sequence folder names for validation; overrides the seeded split when given."""
    every: int = 1
    """Take every n-th frame (consecutive frames are near-duplicates)."""
    min_visible_pixels: int = 100
    classes: ClassTable | None = None
    """The class numbering; None: COCO's (``ClassTable.coco`` of the sequences' classes)."""


def split_sequences(names: list[str], options: ExportOptions) -> dict[str, str]:
    """Sequence name -> 'train' or 'val'."""
    if options.val:
        unknown = sorted(set(options.val) - set(names))
        if unknown:
            raise InputError(f"--val {unknown[0]}: not among the exported sequences")
        return {n: "val" if n in options.val else "train" for n in names}
    order = sorted(names)
    rng = np.random.default_rng(options.seed)
    rng.shuffle(order)
    n_val = 0
    if options.val_fraction > 0 and len(order) >= 2:  # both parts get at least one sequence
        n_val = min(max(math.ceil(options.val_fraction * len(order)), 1), len(order) - 1)
    return {n: "val" if i < n_val else "train" for i, n in enumerate(order)}


def export_dataset(roots: list[Path], out: Path, options: ExportOptions, overwrite: bool = False) -> dict:
    root = dataset_root(out)
    sequences = [Sequence.open(r) for r in roots]
    for seq in sequences:
        if not seq.is_generated:
            raise InputError(f"{seq.root}: export needs generated sequences (with gt/objects.jsonl)")
    names = [s.root.name for s in sequences]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(f"two sequences are named {dup!r}: image names would collide")
    split = split_sequences(names, options)
    present = {o.class_name for s in sequences for f in _objects(s) for o in f}
    table = options.classes or ClassTable.coco(present)
    with StagedOutput(out, OutputKind.DATASET, overwrite=overwrite, inputs=tuple(roots)) as staged:
        files = _DatasetFiles(staged.path, out)
        exporter = _Exporter(files, table, present, options, root)
        total = sum(len(range(0, len(s), options.every)) for s in sequences)
        with progress_bar(total=total, desc="export", unit="frame", leave=False) as bar:
            for seq in sequences:
                exporter.add_sequence(seq, split[seq.root.name], bar)
        summary = exporter.finish(split)
        staged.commit()
    return summary


def dataset_root(out: Path) -> str:
    """The dataset folder's absolute path as data.yaml's ``path``, checked before any work.

    Ultralytics documents ``path`` as the dataset root, "relative to 'path'" for train and
    val; a relative root is looked up against the working directory and then its datasets
    folder, never against data.yaml's own folder (``path: .`` found nothing from anywhere but
    the dataset folder). An absolute path works from every working directory; a moved folder
    needs this one line changed, which the file's comment says."""
    root = str(out.resolve())
    try:
        root.encode("utf-8")
    except UnicodeEncodeError:
        raise InputError(f"{out}: the folder's path is not UTF-8, which data.yaml cannot hold") from None
    return root


class _DatasetFiles:
    """Writes inside the staged dataset; a failed write names the dataset and the cause.

    ``shutil.copyfile`` named the *source* frame when the disk filled ("seqs/s1/rgb/1.png: No
    space left on device"), which sent users to the wrong disk.
    """

    def __init__(self, root: Path, shown: Path) -> None:
        self.root = root
        self.shown = shown

    def mkdirs(self, *relative: str) -> None:
        for name in relative:
            self._do(name, lambda path: path.mkdir(parents=True))

    def write(self, relative: str, data: bytes | str) -> Path:
        raw = data.encode("utf-8") if isinstance(data, str) else data
        return self._do(relative, lambda path: path.write_bytes(raw))

    def _do(self, relative: str, action) -> Path:
        path = self.root / relative
        try:
            action(path)
        except OSError as exc:
            raise OutputError(
                f"{self.shown}: cannot write the output ({exc.strerror or exc}, at {relative})"
            ) from None
        return path


class _Exporter:
    """Collects one dataset: images and YOLO labels as frames come, COCO and splits at the end."""

    def __init__(
        self, files: _DatasetFiles, table: ClassTable, present: set[str], options: ExportOptions, root: str
    ) -> None:
        self.files = files
        self.table = table
        self.present = present
        self.class_id = dict(table.ids)
        self.options = options
        self.root = root
        self.skipped: dict[str, int] = {}
        categories = [{"id": i, "name": c} for i, c in zip(table.category_ids, table.names, strict=True)]
        self.coco = {part: {"images": [], "annotations": [], "categories": categories} for part in PARTS}
        self.counts = {part: {"images": 0, "boxes": 0} for part in PARTS}
        files.mkdirs(*(f"{kind}/{part}" for kind in ("images", "labels") for part in PARTS), "annotations")

    def add_sequence(self, seq: Sequence, part: str, bar: Any) -> None:
        objects = _objects(seq)
        real_root = seq.root.resolve()
        for i in range(0, len(seq), self.options.every):
            stem = f"{seq.root.name}_{timestamp_name(seq.frames[i].timestamp_s)}"
            image = self.files.write(
                f"images/{part}/{stem}.png", read_inside(real_root, seq.frames[i].rgb_path)
            )
            check_frame_copy(seq, i, image)
            image_id = len(self.coco[part]["images"]) + 1
            k = seq.intrinsics
            self.coco[part]["images"].append(
                {"id": image_id, "file_name": f"{stem}.png", "width": k.width, "height": k.height}
            )
            lines = self._boxes(objects[i], part, image_id, k.width, k.height)
            self.files.write(f"labels/{part}/{stem}.txt", "".join(line + "\n" for line in lines))
            self.counts[part]["images"] += 1
            self.counts[part]["boxes"] += len(lines)
            bar.update()

    def _boxes(
        self, states: tuple[ObjectState, ...], part: str, image_id: int, width: int, height: int
    ) -> list[str]:
        """YOLO label lines of one frame; the same boxes go into the COCO annotations."""
        lines = []
        for o in states:
            if o.box_xyxy is None or o.visible_pixels < self.options.min_visible_pixels:
                continue
            if o.class_name not in self.class_id:
                self.skipped[o.class_name] = self.skipped.get(o.class_name, 0) + 1
                continue
            x0, y0, x1, y1 = o.box_xyxy
            c = self.class_id[o.class_name]
            lines.append(
                f"{c} {(x0 + x1) / 2 / width:.6f} {(y0 + y1) / 2 / height:.6f} "
                f"{(x1 - x0) / width:.6f} {(y1 - y0) / height:.6f}"
            )
            self.coco[part]["annotations"].append(
                {
                    "id": len(self.coco[part]["annotations"]) + 1,
                    "image_id": image_id,
                    "category_id": self.table.category_ids[c],
                    "bbox": [x0, y0, x1 - x0, y1 - y0],
                    "area": o.visible_pixels,
                    "iscrowd": 0,
                }
            )
        return lines

    def finish(self, split: dict[str, str]) -> dict:
        for part in PARTS:
            self.files.write(f"annotations/instances_{part}.json", json.dumps(self.coco[part]))
        self.files.write("data.yaml", data_yaml(self.root, self.table))
        summary = {
            "classes": list(self.table.names),
            "names_file": self.table.names_file,
            "ids": {c: self.class_id[c] for c in sorted(self.present) if c in self.class_id},
            "appended_classes": list(self.table.appended),
            "splits": {n: split[n] for n in sorted(split)},
            "counts": self.counts,
            "skipped_classes": self.skipped,
            "every": self.options.every,
            "min_visible_pixels": self.options.min_visible_pixels,
        }
        self.files.write("splits.json", dumps_json(summary) + "\n")
        return summary


# -- reading a sequence's files without leaving its folder ------------------------------------


def _objects(seq: Sequence) -> list[tuple[ObjectState, ...]]:
    """The sequence's object records: the labels, so they too must come from inside its folder."""
    path = seq.root / "gt" / "objects.jsonl"
    _check_inside(seq.root.resolve(), path)
    return seq.objects()


def _check_inside(real_root: Path, path: Path) -> Path:
    """``path`` resolved, refused when a link leads it out of the folder ``real_root``."""
    real = path.resolve()
    if real != real_root and real_root not in real.parents:
        raise FileError(
            path, None, f"is a link out of the sequence folder (to {real}); copy the file into the folder"
        )
    return real


def read_inside(real_root: Path, path: Path) -> bytes:
    """The bytes of a frame file, read without following any link out of ``real_root``.

    A sequence may come from someone else (a tarball, a shared drive): ``x/root -> /`` with
    ``x/root/etc/passwd`` listed as a frame once put the password file into a dataset. The
    path is resolved and checked, then opened one component at a time with ``O_NOFOLLOW``
    from the root, so a link swapped in after the check is refused rather than followed.
    """
    relative = _check_inside(real_root, path).relative_to(real_root)
    if not relative.parts:
        raise FileError(path, None, "is the sequence folder, not a frame file")
    fd = os.open(real_root, os.O_RDONLY | os.O_DIRECTORY)
    for part in relative.parts[:-1]:
        fd = _step(fd, part, path, os.O_RDONLY | os.O_DIRECTORY)
    fd = _step(fd, relative.parts[-1], path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO must not block
    try:
        return _read_regular(fd, path)
    finally:
        os.close(fd)


def _step(dir_fd: int, name: str, shown: Path, flags: int) -> int:
    """Open ``name`` in ``dir_fd`` without following a link; ``dir_fd`` is closed either way."""
    try:
        return os.open(name, flags | os.O_NOFOLLOW, dir_fd=dir_fd)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENOTDIR):
            raise FileError(shown, None, "became a link while it was read; it is not followed") from None
        raise FileError(shown, None, f"cannot be read ({exc.strerror or exc})") from None
    finally:
        os.close(dir_fd)


def _read_regular(fd: int, shown: Path) -> bytes:
    """A regular file's bytes, at most ``MAX_IMAGE_BYTES`` of them (the reader's limit for a frame)."""
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise FileError(shown, None, "is not a regular file (a device, pipe or socket), not a PNG image")
        if info.st_size > MAX_IMAGE_BYTES:
            raise FileError(shown, None, f"is {info.st_size} bytes, more than the limit for a PNG image")
        os.set_blocking(fd, True)
        with os.fdopen(fd, "rb", closefd=False) as handle:  # buffered: loops over short reads
            data = handle.read(MAX_IMAGE_BYTES + 1)
    except OSError as exc:
        raise FileError(shown, None, f"cannot be read ({exc.strerror or exc})") from None
    if len(data) > MAX_IMAGE_BYTES:
        raise FileError(shown, None, "grew beyond the limit for a PNG image while read")
    return data


def check_frame_copy(seq: Sequence, index: int, copy: Path) -> None:
    """Decode the exported copy of frame ``index`` with the sequence reader's own checks (a PNG
    of the camera's size, 8-bit RGB, not truncated), so the bytes checked are the bytes exported.
    ``run`` refuses such a frame; a training set must not take it silently."""
    frame = seq.frames[index]
    as_copied = dataclasses.replace(seq, frames=(dataclasses.replace(frame, rgb_path=copy),))
    try:
        as_copied.rgb(0)
    except FileError as exc:
        raise FileError(frame.rgb_path, None, exc.problem) from None


def data_yaml(root: str, table: ClassTable) -> str:
    """Ultralytics' dataset file: ``path`` absolute (``dataset_root``), train and val relative
    to it, ``names`` in id order; written by PyYAML, so any path or name reads back as is."""
    numbering = (
        "COCO's 80 by their index (the bench's desk is dining table 60), then the bench's own from 80"
        if table.names_file is None
        else "the order of the export's --names file"
    )
    head = (
        "# depotbench export-dataset, YOLO format (Ultralytics). `path` is this folder, absolute,\n"
        "# so the file works from any working directory; after moving the folder, set `path` to\n"
        "# its new place (train and val are relative to it).\n"
        f"# Class ids: {numbering}.\n"
    )
    body = {
        "path": root,
        "train": "images/train",
        "val": "images/val",
        "nc": len(table.names),
        "names": dict(enumerate(table.names)),
    }
    return head + yaml.safe_dump(body, sort_keys=False, allow_unicode=True, width=1 << 16)
