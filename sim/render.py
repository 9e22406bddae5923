"""Off-screen RGB, metric z-depth and per-pixel geom ids from MuJoCo's renderer.

One pass gives RGB and depth (exact with ``offsamples = 0``), a second pass
gives segmentation. The GL context belongs to the thread that creates this
object (rendering-notes.md): create one per worker, after any fork.
"""

from __future__ import annotations

import numpy as np

from sim.errors import EnvironmentProblem
from sim.mujoco_env import mujoco


class RenderingUnavailable(EnvironmentProblem):
    """No off-screen OpenGL context could be made."""


class FrameRenderer:
    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
        from mujoco import gl_context

        self.model, self.width, self.height = model, width, height
        try:
            self._gl = gl_context.GLContext(width, height)
            self._gl.make_current()
        except Exception as exc:  # the GL backends raise many types; all mean the same to a user
            raise RenderingUnavailable(
                "MuJoCo could not open an off-screen OpenGL context "
                f"({type(exc).__name__}: {exc}). Install the EGL and Mesa libraries "
                "(Debian/Ubuntu: apt-get install libegl1 libgl1-mesa-dri, or `make system-deps`), "
                "or set MUJOCO_GL=osmesa with libosmesa6."
            ) from exc
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), np.uint8)
        self._depth = np.empty((height, width), np.float32)
        self._seg = np.empty((height, width, 3), np.uint8)
        extent = model.stat.extent
        self._near = np.float32(model.vis.map.znear * extent)
        self._far = np.float32(model.vis.map.zfar * extent)

    def render(self, data: mujoco.MjData, camera_id: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8, z-depth in metres (float32, 0 = nothing), geom ids (-1 = none)."""
        self._gl.make_current()
        self._camera.fixedcamid = camera_id
        scene, flags = self._scene, self._scene.flags
        mujoco.mjv_updateScene(
            self.model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, scene
        )
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        mujoco.mjr_render(self._rect, scene, self._context)
        mujoco.mjr_readPixels(self._rgb, self._depth, self._rect, self._context)
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        mujoco.mjr_render(self._rect, scene, self._context)
        mujoco.mjr_readPixels(self._seg, None, self._rect, self._context)
        rgb = np.flipud(self._rgb).copy()
        depth = self._metric_depth(np.flipud(self._depth))
        seg = np.flipud(self._seg).astype(np.int32)
        segid = seg[:, :, 0] + (seg[:, :, 1] << 8) + (seg[:, :, 2] << 16)
        lookup = np.full(scene.ngeom + 1, -1, dtype=np.int32)
        for k in range(scene.ngeom):
            geom = scene.geoms[k]
            if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM and geom.segid >= 0:
                lookup[geom.segid + 1] = geom.objid
        geom_ids = lookup[np.minimum(segid, scene.ngeom)]
        return rgb, depth, geom_ids

    def _metric_depth(self, buffer: np.ndarray) -> np.ndarray:
        """Reversed-Z depth buffer to metric z-depth, as MuJoCo's Renderer converts it."""
        near, far = self._near, self._far
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        c = np.float32(-0.5) * c - np.float32(0.5)
        d = np.float32(-0.5) * d
        depth = (d / (buffer.astype(np.float64) + c)).astype(np.float32)
        depth[buffer <= 0] = 0.0
        return depth

    def close(self) -> None:
        self._context.free()
        self._gl.free()
