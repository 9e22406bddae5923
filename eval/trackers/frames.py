"""The frames one run feeds its tracker: a sequence, its detections, and masking.

``mask`` blanks RGB and depth inside the boxes of dynamic classes before any
tracker sees them (DynaSLAM-style), so box rejection can be measured on trackers
that take no boxes. External trackers read folders: ``folder`` hands them a view of the
sequence they cannot change it through, or the masked frames as a plain TUM sequence.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from depotbench.core.errors import InputError
from depotbench.detectors.detection import Detection, Prior
from depotbench.eval.trackers.sequence_view import view_of
from depotbench.sim.camera import OrbSlamSettings, orbslam_yaml
from depotbench.sim.sequence import Sequence, timestamp_name
from depotbench.sim.tum_files import write_frame_list


@dataclass(frozen=True)
class MaskSettings:
    """Which boxes blank the frames: dynamic classes at this confidence, grown by this much."""

    dilation_px: float = 0.0
    min_confidence: float = 0.5


def box_mask(shape: tuple[int, int], detections: tuple[Detection, ...], settings: MaskSettings) -> np.ndarray:
    """True inside the (dilated, clipped) boxes of dynamic detections."""
    height, width = shape
    mask = np.zeros(shape, bool)
    grow = settings.dilation_px
    for d in detections:
        if d.prior is not Prior.DYNAMIC or d.confidence < settings.min_confidence:
            continue
        x0, y0, x1, y1 = d.box_xyxy
        c0, r0 = max(0, int(np.floor(x0 - grow))), max(0, int(np.floor(y0 - grow)))
        c1, r1 = min(width, int(np.ceil(x1 + grow))), min(height, int(np.ceil(y1 + grow)))
        mask[r0:r1, c0:c1] = True
    return mask


class FrameSource:
    """A sequence's frames with their (precomputed) detections, masked or not."""

    def __init__(
        self,
        sequence: Sequence,
        detections: Sequence_[tuple[Detection, ...]] | None = None,
        mask: MaskSettings | None = None,
    ) -> None:
        if mask is not None and detections is None:
            raise ValueError("masking needs detections")
        if detections is not None and len(detections) != len(sequence):
            raise ValueError(f"{len(detections)} frames of detections for {len(sequence)} frames")
        self.sequence = sequence
        self._detections = detections
        self.mask = mask

    def __len__(self) -> int:
        return len(self.sequence)

    def timestamp_s(self, index: int) -> float:
        return self.sequence.frames[index].timestamp_s

    def detections(self, index: int) -> tuple[Detection, ...]:
        return self._detections[index] if self._detections is not None else ()

    def all_detections(self) -> tuple[tuple[Detection, ...], ...] | None:
        """Every frame's boxes (None without a detector): what an external tracker is handed."""
        return None if self._detections is None else tuple(self._detections)

    def _blank(self, index: int) -> np.ndarray | None:
        if self.mask is None:
            return None
        size = (self.sequence.intrinsics.height, self.sequence.intrinsics.width)
        return box_mask(size, self.detections(index), self.mask)

    def images(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """RGB (uint8) and depth as stored (uint16), blanked where masked."""
        rgb, depth = self.sequence.rgb(index), self.sequence.depth_raw(index)
        blank = self._blank(index)
        if blank is not None:
            rgb, depth = rgb.copy(), depth.copy()
            rgb[blank] = 0
            depth[blank] = 0
        return rgb, depth

    def folder(self, scratch: Path) -> Path:
        """A TUM folder holding these frames, in ``scratch``: a view of the sequence (its text
        files copied, its frames hard-linked: ``sequence_view``; named as the sequence is,
        since a real folder's name tells its camera), or a masked copy. A program writing into it
        never changes the sequence itself.

        Raises InputError naming the folder when it cannot be written (a full disk, say).
        """
        if self.mask is None:
            root = scratch / "view" / (self.sequence.root.resolve().name or "sequence")
            try:
                return view_of(self.sequence, root)
            except OSError as exc:
                raise InputError(f"{root}: cannot write the sequence's view: {exc.strerror or exc}") from None
        root = scratch / "masked"
        try:
            self._write_masked(root)
        except OSError as exc:
            raise InputError(f"{root}: cannot write the masked frames: {exc.strerror or exc}") from None
        return root

    def _write_masked(self, root: Path) -> None:
        frames = self.sequence.frames
        rgb_names = [f"rgb/{timestamp_name(f.timestamp_s)}.png" for f in frames]
        depth_names = [f"depth/{timestamp_name(f.depth_timestamp_s)}.png" for f in frames]
        for sub in ("rgb", "depth"):
            (root / sub).mkdir(parents=True, exist_ok=True)
        for i in range(len(frames)):
            rgb, depth = self.images(i)
            _write_png(root / rgb_names[i], cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            _write_png(root / depth_names[i], depth)
        rgb_stamps = np.array([f.timestamp_s for f in frames])
        depth_stamps = np.array([f.depth_timestamp_s for f in frames])
        write_frame_list(root / "rgb.txt", "color images (masked)", rgb_stamps, rgb_names)
        write_frame_list(root / "depth.txt", "depth maps (masked)", depth_stamps, depth_names)
        (root / "associations.txt").write_text(
            "".join(
                f"{timestamp_name(f.timestamp_s)} {r} {timestamp_name(f.depth_timestamp_s)} {d}\n"
                for f, r, d in zip(frames, rgb_names, depth_names, strict=True)
            ),
            encoding="utf-8",
        )
        (root / "camera.yaml").write_text(
            orbslam_yaml(self.sequence.intrinsics, OrbSlamSettings(fps=self.sequence.fps)), encoding="utf-8"
        )
        if (self.sequence.root / "groundtruth.txt").is_file():
            shutil.copyfile(self.sequence.root / "groundtruth.txt", root / "groundtruth.txt")


def _write_png(path: Path, image: np.ndarray) -> None:
    """Encoded here and written by Python: ``cv2.imwrite`` on a full disk printed "libpng
    error: Write Error", left a broken PNG and went on."""
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError(f"OpenCV could not encode {path.name} as PNG")
    path.write_bytes(data.tobytes())
