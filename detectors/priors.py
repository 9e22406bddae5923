"""Class priors of method 1: which classes move (dynamic) and which may (potential)."""

from __future__ import annotations

from detectors.detection import Prior

DYNAMIC_CLASSES = frozenset({"person", "dog", "cat", "bird", "pig", "horse", "sheep", "cow"})
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
    }
)


def prior_of(class_name: str) -> Prior:
    if class_name in DYNAMIC_CLASSES:
        return Prior.DYNAMIC
    if class_name in POTENTIAL_CLASSES:
        return Prior.POTENTIAL
    return Prior.STATIC
