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
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sim.errors import InputError
from sim.files import dumps_json
from sim.output import OutputKind, StagedOutput
from sim.sequence import Sequence, timestamp_name


@dataclass(frozen=True)
class ExportOptions:
    val_fraction: float = 0.2
    seed: int = 0
    val: tuple[str, ...] = ()
    """Sequence folder names for validation; overrides the seeded split when given."""
    every: int = 1
    """Take every n-th frame (consecutive frames are near-duplicates)."""
    min_visible_pixels: int = 100
    names: tuple[str, ...] = ()
    """Class names in id order (e.g. COCO's); default: every class in the sequences, sorted."""


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
    sequences = [Sequence.open(r) for r in roots]
    for seq in sequences:
        if not seq.is_generated:
            raise InputError(f"{seq.root}: export needs generated sequences (with gt/objects.jsonl)")
    names = [s.root.name for s in sequences]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(f"two sequences are named {dup!r}: image names would collide")
    split = split_sequences(names, options)
    classes = list(options.names) or sorted({o.class_name for s in sequences for f in s.objects() for o in f})
    class_id = {c: i for i, c in enumerate(classes)}
    skipped: dict[str, int] = {}
    coco = {
        part: {
            "images": [],
            "annotations": [],
            "categories": [{"id": i + 1, "name": c} for i, c in enumerate(classes)],
        }
        for part in ("train", "val")
    }
    counts = {part: {"images": 0, "boxes": 0} for part in ("train", "val")}
    with StagedOutput(out, OutputKind.DATASET, overwrite=overwrite, inputs=tuple(roots)) as staged:
        root = staged.path
        for part in ("train", "val"):
            (root / "images" / part).mkdir(parents=True)
            (root / "labels" / part).mkdir(parents=True)
        (root / "annotations").mkdir()
        total = sum(len(range(0, len(s), options.every)) for s in sequences)
        with tqdm(total=total, desc="export", unit="frame", disable=None, leave=False) as bar:
            for seq in sequences:
                part = split[seq.root.name]
                objects = seq.objects()
                k = seq.intrinsics
                for i in range(0, len(seq), options.every):
                    stem = f"{seq.root.name}_{timestamp_name(seq.frames[i].timestamp_s)}"
                    shutil.copyfile(seq.frames[i].rgb_path, root / "images" / part / f"{stem}.png")
                    image_id = len(coco[part]["images"]) + 1
                    coco[part]["images"].append(
                        {"id": image_id, "file_name": f"{stem}.png", "width": k.width, "height": k.height}
                    )
                    lines = []
                    for o in objects[i]:
                        if o.box_xyxy is None or o.visible_pixels < options.min_visible_pixels:
                            continue
                        if o.class_name not in class_id:
                            skipped[o.class_name] = skipped.get(o.class_name, 0) + 1
                            continue
                        x0, y0, x1, y1 = o.box_xyxy
                        c = class_id[o.class_name]
                        lines.append(
                            f"{c} {(x0 + x1) / 2 / k.width:.6f} {(y0 + y1) / 2 / k.height:.6f} "
                            f"{(x1 - x0) / k.width:.6f} {(y1 - y0) / k.height:.6f}"
                        )
                        coco[part]["annotations"].append(
                            {
                                "id": len(coco[part]["annotations"]) + 1,
                                "image_id": image_id,
                                "category_id": c + 1,
                                "bbox": [x0, y0, x1 - x0, y1 - y0],
                                "area": o.visible_pixels,
                                "iscrowd": 0,
                            }
                        )
                    (root / "labels" / part / f"{stem}.txt").write_text(
                        "".join(line + "\n" for line in lines), encoding="utf-8"
                    )
                    counts[part]["images"] += 1
                    counts[part]["boxes"] += len(lines)
                    bar.update()
        for part in ("train", "val"):
            (root / "annotations" / f"instances_{part}.json").write_text(
                json.dumps(coco[part]), encoding="utf-8"
            )
        (root / "data.yaml").write_text(_data_yaml(classes), encoding="utf-8")
        summary = {
            "classes": classes,
            "splits": {n: split[n] for n in sorted(split)},
            "counts": counts,
            "skipped_classes": skipped,
            "every": options.every,
            "min_visible_pixels": options.min_visible_pixels,
        }
        (root / "splits.json").write_text(dumps_json(summary) + "\n", encoding="utf-8")
        staged.commit()
    return summary


def _data_yaml(classes: list[str]) -> str:
    lines = [
        "# depotbench export (YOLO format); paths relative to this file",
        "path: .",
        "train: images/train",
    ]
    lines += ["val: images/val", "names:"]
    lines += [f"  {i}: {json.dumps(c)}" for i, c in enumerate(classes)]
    return "\n".join(lines) + "\n"
