"""Import MuJoCo with an off-screen GL backend chosen first, and its warnings kept in.

``MUJOCO_GL`` must be set before ``import mujoco`` (rendering-notes.md); every
module of ours that needs MuJoCo imports it from here. MuJoCo's default warning
handler prints and appends to ``MUJOCO_LOG.TXT`` in the current directory, a file
the user never asked for; warnings are counted in ``MjData.warning`` anyway, and
``depotbench.sim.simulation`` turns them into errors.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402


def _ignore(text: str) -> None:
    """MuJoCo's warnings are read from ``MjData.warning``; nothing is printed or logged."""


mujoco.set_mju_user_warning(_ignore)

__all__ = ["mujoco"]
