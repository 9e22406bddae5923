"""Off-screen RGB, metric z-depth, per-pixel instance geoms and unoccluded areas from
MuJoCo's renderer.

A colour pass gives RGB and depth (exact with ``offsamples = 0``). An instance pass
draws only the instances, in their segmentation colours with the depth test: a pixel
shows an instance's geom where that pass's depth equals the colour pass's (the same
triangles through the same transform give the same depth, bit for bit), and the static
world elsewhere. Drawing the world once, not twice, is what makes it cheaper than a
full segmentation pass. Each visible instance's unoccluded area (what it would cover
with everything else removed) is read from the instance pass when no other instance's
window overlaps its own; the others come from a pass that draws only them, each in its
own bit, OR-ed together without a depth test. Geoms wholly outside the camera's view
are left out of every pass: they draw no pixel; a mesh with a far version (fewer
triangles) is drawn by it beyond ``FAR_M``, in every pass alike. The GL context belongs
to the thread that creates this object (rendering-notes.md): create one per worker,
after any fork.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from depotbench.core.errors import EnvironmentProblem
from depotbench.sim.mujoco_env import mujoco
from depotbench.sim.products import product


class RenderingUnavailable(EnvironmentProblem):
    """No off-screen OpenGL context could be made."""


INSTANCE_GROUP, SOLO_GROUP, HIDDEN_GROUP = 2, 3, 5
"""Geom groups: an instance's geoms are in INSTANCE_GROUP (drawn by default), and move to
SOLO_GROUP for a pass that draws that instance alone; the rest of the world is group 0.
Geoms the model puts in HIDDEN_GROUP or above (collision stand-ins) are never drawn."""


FAR_SUFFIX = "_far"
"""A mesh geom named as another with this suffix, on the same body, is that geom's far
version: fewer triangles, drawn instead of it where it is far from the camera."""
FAR_M = 3.0
"""Depth (along the camera's axis, to the geom's centre) beyond which a geom's far
version is drawn in its place, in every pass alike. The figures' triangles are most of
each pass's cost on llvmpipe; at 3 m a person stands about 300 pixels tall (f = 525)."""


@dataclasses.dataclass(frozen=True)
class RenderedFrame:
    """One camera frame and which instance each of its pixels shows."""

    rgb: np.ndarray
    """(H, W, 3) uint8."""
    depth: np.ndarray
    """(H, W) z-depth in metres, float32; 0 where nothing is drawn."""
    geom_ids: np.ndarray
    """(H, W) int32: the instance geom each pixel shows; -1 for the static world (whose
    bodies never move) and for empty pixels."""
    instances: np.ndarray
    """(H, W) uint16: the instance each pixel shows, 0 for the static world."""
    counts: np.ndarray
    """Pixels of each instance id (index 0: the static world and empty pixels), one entry
    for every id ``geom_instance`` names: the visible areas ground truth reports."""
    unoccluded: dict[int, tuple[int, bool]]
    """Per instance with a visible pixel: (pixels it covers with everything else removed,
    whether that area reaches the image border)."""


class FrameRenderer:
    def __init__(
        self,
        model: mujoco.MjModel,
        width: int,
        height: int,
        geom_instance: np.ndarray,
        cull: bool = True,
    ) -> None:
        """``geom_instance``: the instance id of every geom (0 for the static world).
        ``cull``: leave out geoms outside the view (the same pixels)."""
        from mujoco import gl_context

        self.model, self.width, self.height = model, width, height
        self.geom_instance = geom_instance
        self._instance_of = np.append(geom_instance, 0).astype(np.uint16)  # index -1: none
        self._instance_count = int(geom_instance.max(initial=0))
        self._drawn = model.geom_group < HIDDEN_GROUP
        # Culled by their bounding spheres, a little enlarged; planes (rbound 0) never.
        self._cullable = (self._drawn & (model.geom_rbound > 0)) if cull else np.zeros(model.ngeom, bool)
        self._cull_radius = model.geom_rbound * (1 + 1e-6) + 1e-3
        self._near_version, self._far_version = detail_pairs(model)
        model.geom_group[:] = np.where(
            self._drawn, np.where(geom_instance > 0, INSTANCE_GROUP, 0), model.geom_group
        )
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
        if self._scene.maxgeom >= (1 << 16) - 1:
            raise ValueError(f"{model.ngeom} geoms: segmentation reads at most {(1 << 16) - 2}")
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        _sample_textures_bilinear(model, self._context)
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._option = mujoco.MjvOption()
        self._solo = _only_group(SOLO_GROUP)
        self._instances_only = _only_group(INSTANCE_GROUP)
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgba = np.empty((height, width, 4), np.uint8)
        self._depth = np.empty((height, width), np.float32)
        self._seg = np.empty((height, width, 4), np.uint8)
        self._instance_depth = np.empty((height, width), np.float32)
        extent = model.stat.extent
        self._near = np.float32(model.vis.map.znear * extent)
        self._far = np.float32(model.vis.map.zfar * extent)

    def render(self, data: mujoco.MjData, camera_id: int) -> RenderedFrame:
        """The colour pass, the instance pass, and the unoccluded areas of the instances seen."""
        self._gl.make_current()
        rgb, depth = self._colour_pass(data, camera_id)
        front, drawn = self._instance_pass(data, camera_id)
        shown = np.flipud(np.where(self._instance_depth == self._depth, front, -1))
        instances = self._instance_of[shown]
        counts = np.bincount(instances.ravel(), minlength=self._instance_count + 1)
        seen = np.flatnonzero(counts[1:]) + 1
        unoccluded = self._unoccluded_areas(data, camera_id, np.flipud(front), drawn, seen.tolist())
        return RenderedFrame(rgb, depth, shown, instances, counts, unoccluded)

    def _colour_pass(self, data: mujoco.MjData, camera_id: int) -> tuple[np.ndarray, np.ndarray]:
        """RGB and metric depth of the whole scene; the raw depth buffer stays in ``_depth``."""
        self._update_scene(data, camera_id, self._option)
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        mujoco.mjr_render(self._rect, self._scene, self._context)
        self._read((0, 0, self.width, self.height), self._rgba, self._depth)
        rgb = cv2.cvtColor(np.flipud(self._rgba), cv2.COLOR_RGBA2RGB)  # numpy's strided copy: 25x slower
        return rgb, self._metric_depth(np.flipud(self._depth))

    def _instance_pass(self, data: mujoco.MjData, camera_id: int) -> tuple[np.ndarray, list[int]]:
        """The front-most instance geom at each pixel (-1 = none) with only the instances
        drawn, bottom row first, their depth buffer in ``_instance_depth``; and the
        instances drawn."""
        self._update_scene(data, camera_id, self._instances_only)
        lookup = self._segment_lookup()
        front = self._segment(self._instance_depth, lookup)
        return front, np.unique(self.geom_instance[lookup[lookup >= 0]]).tolist()

    def _segment(self, depth: np.ndarray | None = None, lookup: np.ndarray | None = None) -> np.ndarray:
        """Geom ids (-1 = none) of a segmentation pass of the current scene, bottom row
        first; its depth buffer into ``depth`` if given. ``lookup``: the scene's
        ``_segment_lookup``, where the caller has it already."""
        self._draw_segmentation()
        self._read((0, 0, self.width, self.height), self._seg, depth)
        # A pixel's colour is segid + 1 in 24 bits (R lowest); below 2^16 blue is 0, so the
        # id is the little-endian 16 bits of red and green, read in place.
        seg = self._seg
        segid = np.ndarray(seg.shape[:2], np.dtype("<u2"), seg, 0, seg.strides[:2])
        return (self._segment_lookup() if lookup is None else lookup)[segid]

    def _segment_lookup(self) -> np.ndarray:
        """The geom id of each segmentation colour (segid + 1) of the current scene; -1 for
        colours no geom has (black: none drawn)."""
        scene = self._scene
        lookup = np.full(1 << 16, -1, dtype=np.int32)
        geoms = scene.geoms  # each access of the property builds the whole list again
        for k in range(scene.ngeom):
            geom = geoms[k]
            if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM and geom.segid >= 0:
                lookup[geom.segid + 1] = geom.objid
        return lookup

    def _unoccluded_areas(
        self, data: mujoco.MjData, camera_id: int, front: np.ndarray, drawn: list[int], seen: list[int]
    ) -> dict[int, tuple[int, bool]]:
        """``unoccluded`` of the instances ``seen``. One whose window overlaps no other drawn
        instance's has nothing in front of it in the instance pass (``front``, top row
        first), so its area is read there; the rest take ``unoccluded``'s passes."""
        windows = self._windows(data, camera_id, drawn)
        out, crowded = {}, {}
        for instance in seen:
            window = windows[instance]
            if any(_overlap(window, windows[other]) for other in drawn if other != instance):
                crowded[instance] = window
                continue
            row0, col0, row1, col1 = window
            covered = self._instance_of[front[row0:row1, col0:col1]] == instance
            out[instance] = (int(covered.sum()), bool(self._on_border(covered, window).any()))
        out.update(self._bit_pass_areas(data, camera_id, crowded))
        return {instance: out[instance] for instance in seen}

    def _draw_segmentation(self) -> None:
        """Draw the current scene with each geom in its id colour (black where none)."""
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        mujoco.mjr_render(self._rect, self._scene, self._context)

    def unoccluded(
        self, data: mujoco.MjData, camera_id: int, instances: list[int]
    ) -> dict[int, tuple[int, bool]]:
        """Per instance asked: (pixels it covers with everything else removed, whether that
        area reaches the image border). Exact: one pass draws the instances without the
        rest of the world, each in its own bit of the 24-bit colour, OR-ed into the
        framebuffer with no depth buffer, so a pixel holds the bit of every instance that
        covers it, hidden or not. Instances whose pixel windows (which hold their
        projections) are apart share a bit; past 24 bits, another pass."""
        self._gl.make_current()
        return self._bit_pass_areas(data, camera_id, self._windows(data, camera_id, instances))

    def _windows(
        self, data: mujoco.MjData, camera_id: int, instances: list[int]
    ) -> dict[int, tuple[int, int, int, int]]:
        """Each instance's pixel window (``_window`` of its projected box)."""
        boxes = self._projected_boxes(data, camera_id, instances)
        return {i: self._window(box) for i, box in zip(instances, boxes, strict=True)}

    def _bit_pass_areas(
        self, data: mujoco.MjData, camera_id: int, windows: dict[int, tuple[int, int, int, int]]
    ) -> dict[int, tuple[int, bool]]:
        """``unoccluded`` of the instances of ``windows``, by the OR-ed bit passes."""
        out = {}
        for bits in _bit_passes(list(windows), windows):
            self._draw_bits(data, camera_id, bits)
            corners = np.array([windows[i] for i in bits])
            union = (*corners[:, :2].min(axis=0).tolist(), *corners[:, 2:].max(axis=0).tolist())
            words = self._read_words(union)
            for instance, bit in bits.items():
                row0, col0, row1, col1 = windows[instance]
                part = words[row0 - union[0] : row1 - union[0], col0 - union[1] : col1 - union[1]]
                covered = (part & (1 << bit)) > 0
                out[instance] = (int(covered.sum()), bool(self._on_border(covered, windows[instance]).any()))
        return out

    def _draw_bits(self, data: mujoco.MjData, camera_id: int, bits: dict[int, int]) -> None:
        """Draw the instances of ``bits`` alone, each geom in its instance's bit, OR-ed."""
        from OpenGL import GL

        groups = self.model.geom_group
        owned = np.isin(self.geom_instance, list(bits)) & self._drawn
        groups[owned] = SOLO_GROUP
        try:
            self._update_scene(data, camera_id, self._solo)
        finally:
            groups[owned] = INSTANCE_GROUP
        bit_of = np.full(int(self.geom_instance.max()) + 1, -1)
        bit_of[list(bits)] = list(bits.values())
        for geom in self._scene.geoms[: self._scene.ngeom]:
            # A geom's colour is segid + 1 in 24 bits (R lowest): 2^bit.
            is_geom = geom.objtype == mujoco.mjtObj.mjOBJ_GEOM
            geom.segid = (1 << int(bit_of[self.geom_instance[geom.objid]])) - 1 if is_geom else -1
        context = self._context
        # Without a depth buffer every fragment passes (mjr_render enables the depth test);
        # the logic op, which mjr_render leaves alone, ORs each into the pixel.
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, context.offFBO)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_STENCIL_ATTACHMENT, GL.GL_RENDERBUFFER, 0)
        GL.glEnable(GL.GL_COLOR_LOGIC_OP)
        GL.glLogicOp(GL.GL_OR)
        try:
            self._draw_segmentation()
        finally:
            GL.glDisable(GL.GL_COLOR_LOGIC_OP)
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, context.offFBO)
            GL.glFramebufferRenderbuffer(
                GL.GL_FRAMEBUFFER, GL.GL_DEPTH_STENCIL_ATTACHMENT, GL.GL_RENDERBUFFER, context.offDepthStencil
            )

    def _read_words(self, window: tuple[int, int, int, int]) -> np.ndarray:
        """The 24-bit colours (R lowest) of ``window`` of the last pass, top row first."""
        row0, col0, row1, col1 = window
        rgba = np.empty((row1 - row0, col1 - col0, 4), np.uint8)
        self._read((col0, self.height - row1, col1 - col0, row1 - row0), rgba)
        return np.flipud(rgba.view("<u4")[:, :, 0] & 0xFFFFFF)

    def _read(
        self, rect: tuple[int, int, int, int], rgba: np.ndarray, depth: np.ndarray | None = None
    ) -> None:
        """Read (left, bottom, width, height) of the offscreen buffer as RGBA (and depth), bottom
        row first. The same pixels as ``mjr_readPixels``, whose RGB llvmpipe converts from its
        RGBA in a slow path: the whole frame's RGB and depth took 1.14 ms, RGBA and depth 0.67."""
        from OpenGL import GL

        if self._context.offSamples:  # a multisampled buffer: MuJoCo resolves it as it reads
            rgb = np.empty((*rgba.shape[:2], 3), np.uint8)
            mujoco.mjr_readPixels(rgb, depth, mujoco.MjrRect(*rect), self._context)
            rgba[:, :, :3], rgba[:, :, 3] = rgb, 255
            return
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._context.offFBO)
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
        GL.glReadPixels(*rect, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, rgba)
        if depth is not None:
            GL.glReadPixels(*rect, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, depth)

    def _window(self, box: np.ndarray) -> tuple[int, int, int, int]:
        """(row0, col0, row1, col1), top row first, of the pixels whose centres a projected
        box (u0, v0, u1, v1 about the image centre) may hold, a pixel to spare."""
        col0 = int(np.clip(np.floor(box[0] + self.width / 2) - 1, 0, self.width - 1))
        col1 = int(np.clip(np.ceil(box[2] + self.width / 2) + 1, col0 + 1, self.width))
        row0 = int(np.clip(np.floor(box[1] + self.height / 2) - 1, 0, self.height - 1))
        row1 = int(np.clip(np.ceil(box[3] + self.height / 2) + 1, row0 + 1, self.height))
        return row0, col0, row1, col1

    def _on_border(self, pixels: np.ndarray, window: tuple[int, int, int, int]) -> np.ndarray:
        """The values of ``pixels`` (a window of the image) that lie on the image's border."""
        row0, col0, row1, col1 = window
        parts = [pixels[0]] if row0 == 0 else []
        if row1 == self.height:
            parts.append(pixels[-1])
        if col0 == 0:
            parts.append(pixels[:, 0])
        if col1 == self.width:
            parts.append(pixels[:, -1])
        return np.concatenate(parts) if parts else np.zeros(0, pixels.dtype)

    def _projected_boxes(self, data: mujoco.MjData, camera_id: int, instances: list[int]) -> np.ndarray:
        """(u0, v0, u1, v1) holding each instance's projection, from the corners of its
        geoms' bounding boxes (conservative; the whole plane if a corner is behind the
        camera), one row per instance. u, v are pixel offsets from the image centre. All
        instances' corners in one go: one instance at a time cost 0.1 ms each."""
        geoms = np.flatnonzero(np.isin(self.geom_instance, instances))
        aabb = self.model.geom_aabb[geoms]  # (centre, half size) in the geom's frame
        local = aabb[:, None, :3] + _BOX_CORNERS[None] * aabb[:, None, 3:]
        rotation = data.geom_xmat[geoms].reshape(-1, 3, 3)
        world = np.einsum("gij,gkj->gki", rotation, local) + data.geom_xpos[geoms][:, None]
        camera = product(
            world.reshape(-1, 3) - data.cam_xpos[camera_id], data.cam_xmat[camera_id].reshape(3, 3)
        )
        depth = -camera[:, 2]  # MuJoCo cameras look along -z
        view = camera_view(self.model, camera_id, self.width, self.height)
        with np.errstate(divide="ignore", invalid="ignore"):  # behind the camera: replaced below
            u = view.fx * camera[:, 0] / depth + view.shift_px[0]
            v = -view.fy * camera[:, 1] / depth + view.shift_px[1]
        owner = np.repeat(self.geom_instance[geoms], len(_BOX_CORNERS))
        boxes = np.empty((len(instances), 4))
        for row, instance in enumerate(instances):
            mine = owner == instance
            if (depth[mine] <= 1e-6).any():
                boxes[row] = (-np.inf, -np.inf, np.inf, np.inf)
            else:
                boxes[row] = (u[mine].min(), v[mine].min(), u[mine].max(), v[mine].max())
        return boxes

    def _update_scene(self, data: mujoco.MjData, camera_id: int, option: mujoco.MjvOption) -> None:
        self._camera.fixedcamid = camera_id
        groups = self.model.geom_group
        hidden = self._outside_view(data, camera_id)
        far = self._far_from(data, camera_id)
        hidden[self._near_version[far]] = True
        hidden[self._far_version[~far]] = True
        kept = groups[hidden]
        groups[hidden] = HIDDEN_GROUP
        try:
            mujoco.mjv_updateScene(
                self.model, data, option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
            )
        finally:
            groups[hidden] = kept

    def _far_from(self, data: mujoco.MjData, camera_id: int) -> np.ndarray:
        """Which geoms with a far version lie beyond ``FAR_M``, by their near version's centre."""
        offset = data.geom_xpos[self._near_version] - data.cam_xpos[camera_id]
        axis = data.cam_xmat[camera_id].reshape(3, 3)[:, 2]  # MuJoCo cameras look along -z
        return product(offset, -axis) > FAR_M

    def _outside_view(self, data: mujoco.MjData, camera_id: int) -> np.ndarray:
        """Which geoms lie wholly outside the camera's view: each bounding sphere on the far
        side of one of the frustum's side planes, or behind the camera."""
        camera = product(data.geom_xpos - data.cam_xpos[camera_id], data.cam_xmat[camera_id].reshape(3, 3))
        x, y, z = camera[:, 0], camera[:, 1], -camera[:, 2]  # MuJoCo cameras look along -z
        radius = self._cull_radius
        left, right, down, up = camera_view(self.model, camera_id, self.width, self.height).tangents
        outside = z < -radius
        for offset, tan in ((x, right), (-x, left), (y, up), (-y, down)):
            outside |= offset - tan * z > radius * np.sqrt(1 + tan * tan)  # distance to the plane
        return outside & self._cullable

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


@dataclasses.dataclass(frozen=True)
class CameraView:
    """How a MuJoCo camera maps its frame onto a width x height image, as MuJoCo draws it."""

    fx: float
    fy: float
    shift_px: tuple[float, float]
    """Where the optical axis meets the image, right and down of the image's centre."""
    tangents: tuple[float, float, float, float]
    """Tangents of the view's half-angles to the left, right, down and up of the axis."""


def camera_view(model: mujoco.MjModel, camera_id: int, width: int, height: int) -> CameraView:
    """The view of a ``fovy`` camera (square pixels, centred axis, the image's aspect) or of
    one with a sensor size, whose frustum spans (S/2 -+ p) / f either side of the axis
    (engine_vis_visualize.c getFrustum; ``world.camera_attributes`` writes it)."""
    sensor = model.cam_sensorsize[camera_id].astype(np.float64)
    if not sensor[1] > 0:
        tan_v = np.tan(np.radians(model.cam_fovy[camera_id]) / 2)
        tan_u = tan_v * width / height
        focal = (height / 2) / tan_v
        return CameraView(focal, focal, (0.0, 0.0), (tan_u, tan_u, tan_v, tan_v))
    f_x, f_y, p_x, p_y = model.cam_intrinsic[camera_id].astype(np.float64)
    left, right = (sensor[0] / 2 - p_x) / f_x, (sensor[0] / 2 + p_x) / f_x
    up, down = (sensor[1] / 2 - p_y) / f_y, (sensor[1] / 2 + p_y) / f_y
    fx, fy = width / (left + right), height / (up + down)
    return CameraView(fx, fy, (left * fx - width / 2, up * fy - height / 2), (left, right, down, up))


def _sample_textures_bilinear(model: mujoco.MjModel, context: mujoco.MjrContext) -> None:
    """Sample every texture bilinearly from its nearest mip level instead of MuJoCo's
    trilinear blend of two levels. On llvmpipe this takes about a fifth off the RGB pass
    (benchmarks/render.py); pixels move by half a grey level on average."""
    from OpenGL import GL  # a dependency of mujoco's own GL contexts

    for i in range(context.ntexture):
        target = (
            GL.GL_TEXTURE_2D
            if model.tex_type[i] == mujoco.mjtTexture.mjTEXTURE_2D
            else GL.GL_TEXTURE_CUBE_MAP
        )
        GL.glBindTexture(target, int(context.texture[i]))
        GL.glTexParameteri(target, GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR_MIPMAP_NEAREST)
        GL.glBindTexture(target, 0)


_BOX_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
"""The 8 corners of a unit box, as signs of its half sizes."""


def detail_pairs(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """The ids of the geoms that have a far version, and of their far versions (named
    for them with ``FAR_SUFFIX``, on the same body)."""
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in range(model.ngeom)]
    ids = {name: g for g, name in enumerate(names) if name}
    far = [g for g, name in enumerate(names) if name.endswith(FAR_SUFFIX)]
    near = [ids.get(names[g].removesuffix(FAR_SUFFIX), -1) for g in far]
    for n, f in zip(near, far, strict=True):
        if n < 0 or model.geom_bodyid[n] != model.geom_bodyid[f]:
            raise ValueError(f"geom {names[f]!r} is a far version of no geom on its body")
    return np.array(near, dtype=int), np.array(far, dtype=int)


def _only_group(group: int) -> mujoco.MjvOption:
    """Scene options that draw the geoms of one group alone."""
    option = mujoco.MjvOption()
    option.geomgroup[:] = [g == group for g in range(len(option.geomgroup))]
    return option


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    """Whether two (row0, col0, row1, col1) windows share a pixel."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


BITS = 24
"""Instances one unoccluded pass tells apart: the bits of an RGB8 colour."""


def _bit_passes(instances: list[int], windows: dict[int, tuple[int, int, int, int]]) -> list[dict[int, int]]:
    """Each instance's bit, pass by pass: instances whose windows overlap get different
    bits; those apart may share one, as neither can stray into the other's window."""
    passes: list[dict[int, int]] = []
    for instance in instances:
        for bits in passes:
            taken = {bit for other, bit in bits.items() if _overlap(windows[instance], windows[other])}
            free = next((bit for bit in range(BITS) if bit not in taken), None)
            if free is not None:
                bits[instance] = free
                break
        else:
            passes.append({instance: 0})
    return passes
