"""Per-object ground truth of one frame, as stored in ``gt/objects.jsonl``.

Priors are plain strings here (``dynamic``, ``potential``, ``static``) so that
the bottom layer of the import graph needs no detector types; the list is the actor
kinds' (``depotbench.sim.kinds.PRIORS``), whose classes and priors ground truth carries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from depotbench.sim.kinds import PRIORS


@dataclass(frozen=True)
class ObjectState:
    """One instance in one frame.

    ``box_xyxy`` is the visible box in pixel-edge coordinates: pixel (u, v)
    covers [u, u+1) x [v, v+1), so a mask spanning columns 10..19 has
    x0 = 10, x1 = 20. ``None`` when no pixel is visible.
    """

    instance_id: int
    class_name: str
    prior: str
    position_m: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]
    linear_velocity_mps: tuple[float, float, float]
    angular_velocity_radps: tuple[float, float, float]
    moving: bool
    box_xyxy: tuple[int, int, int, int] | None
    visible_pixels: int
    unoccluded_pixels: int | None = None
    """Pixels of the image it would cover with everything else removed (None when it has no
    visible pixel, and in sequences written before this was recorded)."""
    truncated: bool | None = None
    """Whether the image border cuts it (its unoccluded area reaches the border), as KITTI
    and COCO users expect; None when it has no visible pixel."""

    @property
    def visible_fraction(self) -> float | None:
        """Visible over unoccluded pixels: 1 in plain view, towards 0 behind things."""
        if self.unoccluded_pixels is None or self.visible_pixels == 0:
            return None
        return self.visible_pixels / self.unoccluded_pixels

    def __post_init__(self) -> None:
        if not 0 < self.instance_id < 65536:
            raise ValueError(f"instance_id must be in 1..65535, got {self.instance_id}")
        if self.prior not in PRIORS:
            raise ValueError(f"prior must be one of {PRIORS}, got {self.prior!r}")
        for name in ("position_m", "quat_xyzw", "linear_velocity_mps", "angular_velocity_radps"):
            if not all(math.isfinite(v) for v in getattr(self, name)):
                raise ValueError(f"{name} of instance {self.instance_id} is not finite")
        if self.visible_pixels < 0:
            raise ValueError("visible_pixels must be >= 0")
        if (self.box_xyxy is None) != (self.visible_pixels == 0):
            raise ValueError("an instance has a box exactly when it has visible pixels")
        if self.unoccluded_pixels is not None and self.unoccluded_pixels < self.visible_pixels:
            raise ValueError(
                f"unoccluded_pixels {self.unoccluded_pixels} of instance {self.instance_id} is below "
                f"its visible_pixels {self.visible_pixels}"
            )
        if self.box_xyxy is not None:
            x0, y0, x1, y1 = self.box_xyxy
            if not (0 <= x0 < x1 and 0 <= y0 < y1):
                raise ValueError(f"box_xyxy {self.box_xyxy} of instance {self.instance_id} is empty")

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.instance_id,
            "class": self.class_name,
            "prior": self.prior,
            "position_m": list(self.position_m),
            "quat_xyzw": list(self.quat_xyzw),
            "linear_velocity_mps": list(self.linear_velocity_mps),
            "angular_velocity_radps": list(self.angular_velocity_radps),
            "moving": self.moving,
            "box_xyxy": None if self.box_xyxy is None else list(self.box_xyxy),
            "visible_pixels": self.visible_pixels,
            "unoccluded_pixels": self.unoccluded_pixels,
            "visible_fraction": None if self.visible_fraction is None else round(self.visible_fraction, 4),
            "truncated": self.truncated,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ObjectState:
        box = data["box_xyxy"]
        if not isinstance(data["moving"], bool):
            raise ValueError(f"moving must be true or false, got {data['moving']!r}")
        return cls(
            instance_id=int(data["id"]),
            class_name=str(data["class"]),
            prior=str(data["prior"]),
            position_m=_numbers(data["position_m"], 3, float),  # type: ignore[arg-type]
            quat_xyzw=_numbers(data["quat_xyzw"], 4, float),  # type: ignore[arg-type]
            linear_velocity_mps=_numbers(data["linear_velocity_mps"], 3, float),  # type: ignore[arg-type]
            angular_velocity_radps=_numbers(data["angular_velocity_radps"], 3, float),  # type: ignore[arg-type]
            moving=data["moving"],
            box_xyxy=None if box is None else _numbers(box, 4, int),  # type: ignore[arg-type]
            visible_pixels=int(data["visible_pixels"]),
            unoccluded_pixels=_optional(data, "unoccluded_pixels", int),
            truncated=_optional(data, "truncated", bool),
        )


def _optional(data: dict[str, Any], name: str, kind: type) -> Any:
    """A field later formats added: absent or null reads as None."""
    value = data.get(name)
    if value is None:
        return None
    if kind is bool and not isinstance(value, bool):
        raise ValueError(f"{name} must be true, false or null, got {value!r:.60}")
    if kind is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise ValueError(f"{name} must be an integer or null, got {value!r:.60}")
    return value


def _numbers(values: Any, n: int, kind: type) -> tuple:
    if not isinstance(values, list) or len(values) != n:
        raise ValueError(f"expected a list of {n} numbers, got {values!r:.60}")
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        raise ValueError(f"expected numbers, got {values!r:.60}")
    return tuple(kind(v) for v in values)


def boxes_and_counts(instances: np.ndarray, n_instances: int) -> tuple[list, np.ndarray]:
    """Per instance id 1..n: visible box (pixel-edge xyxy) or None, and pixel count."""
    return visible_boxes(instances, n_instances), np.bincount(instances.ravel(), minlength=n_instances + 1)


def visible_boxes(instances: np.ndarray, n_instances: int) -> list:
    """Per instance id 1..n: visible box (pixel-edge xyxy) or None (generation takes the
    pixel counts from the renderer, which has them already)."""
    from scipy import ndimage  # here: 0.2-0.7 s that every command reading ground truth paid at start

    return [
        None if sl is None else (sl[1].start, sl[0].start, sl[1].stop, sl[0].stop)
        for sl in ndimage.find_objects(instances, max_label=n_instances)
    ]
