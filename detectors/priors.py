"""Class priors of method 1: which classes move (dynamic) and which may (potential).

A detector's class names reach SLAM through a ``PriorTable``, after
``depotbench.detectors.coco.bench_name`` turned a model's spellings into the bench's
('tvmonitor' is 'tv'; COCO's 'dining table' is the bench's 'desk'). The default table
knows COCO's names and the bench's own; ``--class-prior NAME=PRIOR`` changes a
row, its name read the same way (``--class-prior 'dining table=static'`` is the desk's).
COCO has no pig: YOLOX-nano calls the bench's pigs dog, sheep or person (dynamic here, so
they are still rejected) or teddy bear (static by default).
"""

from __future__ import annotations

from dataclasses import dataclass

from depotbench.detectors.coco import bench_name
from depotbench.detectors.detection import Prior

DYNAMIC_CLASSES = frozenset(
    {"person", "dog", "cat", "bird", "pig", "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe"}
)
POTENTIAL_CLASSES = frozenset(
    {
        "chair",
        "desk",
        "dining table",
        "cup",
        "book",
        "laptop",
        "tv",
        "bottle",
        "keyboard",
        "mouse",
        "backpack",
        "handbag",
        "suitcase",
        "bicycle",
        "car",
        "motorcycle",
        "truck",
        "bus",
        "cell phone",
        "remote",
        "umbrella",
    }
)


def prior_of(class_name: str) -> Prior:
    return DEFAULT_PRIORS.prior(class_name)


@dataclass(frozen=True)
class PriorTable:
    """Class name to prior: the default sets, with overrides on top."""

    overrides: tuple[tuple[str, Prior], ...] = ()

    def prior(self, class_name: str) -> Prior:
        for name, prior in self.overrides:
            if name == class_name:
                return prior
        if class_name in DYNAMIC_CLASSES:
            return Prior.DYNAMIC
        if class_name in POTENTIAL_CLASSES:
            return Prior.POTENTIAL
        return Prior.STATIC

    def with_overrides(self, settings: dict[str, str]) -> PriorTable:
        rows = dict(self.overrides)
        for name, text in settings.items():
            try:
                rows[bench_name(name)] = Prior(text)
            except ValueError:
                choices = ", ".join(p.value for p in Prior)
                raise ValueError(f"--class-prior {name}={text!r}: choose one of {choices}") from None
        return PriorTable(tuple(sorted(rows.items())))


DEFAULT_PRIORS = PriorTable()
