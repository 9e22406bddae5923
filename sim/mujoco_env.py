"""Import MuJoCo with an off-screen GL backend chosen first.

``MUJOCO_GL`` must be set before ``import mujoco`` (rendering-notes.md); every
module of ours that needs MuJoCo imports it from here.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402

__all__ = ["mujoco"]
