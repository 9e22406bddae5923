"""Full pinhole intrinsics (fx != fy, an off-centre principal point) rendered exactly.

The references are closed forms, not the renderer: a sphere's image is an ellipse whose
centre follows from its cone of sight, a plane's depth at each pixel from its ray, and the
floor of a generated sequence lies at z = 0. Each check also measures the centred camera
the simulator used to assume, to show that the check would catch it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from depotbench.core.camera import Intrinsics
from depotbench.core.errors import InputError
from depotbench.scenes.schema import parse_scenario, to_scenario
from depotbench.sim.spec import CameraSpec, ScenarioSpec, default_scenario, spec_from_dict
from depotbench.sim.world import at_size, build_world, camera_attributes, intrinsics_of

TUM_FR3 = {"fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6}
"""TUM fr3's camera at 640x480 (ORB-SLAM2's Examples/RGB-D/TUM3.yaml)."""

SKEWED = Intrinsics(fx=140.0, fy=147.0, cx=61.0, cy=71.0, width=160, height=120)
"""fy 5 % above fx and the axis 18.5 px left of and 11.5 px below the centre of a 160x120
image, on whole pixels (the pixel at the principal point looks down the axis)."""
CENTRED = dataclasses.replace(SKEWED, fy=SKEWED.fx, cx=79.5, cy=59.5)
"""What the simulator assumed before: square pixels, the axis through the image centre."""


def _render(intrinsics: Intrinsics, bodies: list[tuple[list[float], dict]]):
    """Render bodies (OpenCV camera-frame position, geom), each its own instance, seen by
    a camera with ``intrinsics`` at the origin; the frame and the renderer's view."""
    from depotbench.sim.mujoco_env import mujoco
    from depotbench.sim.render import FrameRenderer, camera_view

    spec = mujoco.MjSpec()
    spec.visual.quality.offsamples = 0  # as the bench's worlds: exact pixels
    spec.worldbody.add_camera(name="camera", pos=[0, 0, 0], **camera_attributes(intrinsics))
    for k, ((x, y, z), geom) in enumerate(bodies):  # OpenCV to MuJoCo's camera frame (y up, -z ahead)
        spec.worldbody.add_body(name=f"b{k}", pos=[x, -y, -z]).add_geom(**geom)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    body_instance = np.zeros(model.nbody, np.uint16)
    for k in range(len(bodies)):
        body_instance[model.body(f"b{k}").id] = k + 1
    renderer = FrameRenderer(model, intrinsics.width, intrinsics.height, body_instance[model.geom_bodyid])
    try:
        return renderer.render(data, 0), camera_view(model, 0, intrinsics.width, intrinsics.height)
    finally:
        renderer.close()


def ellipse_centre(k: Intrinsics, point: np.ndarray, radius: float) -> np.ndarray:
    """Centre (u, v) of a sphere's image. Its silhouette cone (half-angle a, axis at angle t
    to the optical axis) cuts the image plane in an ellipse whose centre lies in the axis's
    direction at tan = sin t cos t / (cos^2 t - sin^2 a), a little beyond tan t; the pixel
    map (fx, fy, cx, cy) is affine, so it keeps an ellipse's centre its centre."""
    distance = float(np.linalg.norm(point))
    cos_t = point[2] / distance
    sin_t = math.sqrt(max(0.0, 1 - cos_t**2))
    lateral = float(np.linalg.norm(point[:2]))
    direction = point[:2] / lateral if lateral > 0 else np.zeros(2)
    x, y = direction * sin_t * cos_t / (cos_t**2 - (radius / distance) ** 2)
    return np.array([k.fx * x + k.cx, k.fy * y + k.cy])


@pytest.mark.render
def test_spheres_land_where_the_pinhole_puts_them():
    """Five spheres' mask centroids are their closed-form ellipse centres within 0.3 px
    through a camera with fx != fy and an off-centre axis (a centred camera misses each by
    over 5 px). The renderer's own projection agrees: each sphere's unoccluded area, read in
    a window it projects, is all of its pixels; and a sphere in the strip only the
    off-centre view holds (right of where a centred frustum ends) is drawn, not culled."""
    from depotbench.sim.mujoco_env import mujoco

    k, radius = SKEWED, 0.1
    beyond_centred_view = ((k.width - 8 - k.cx) / k.fx * 2.5, 0.0, 2.5)  # u = W - 8
    points = [(0.0, 0.0, 2.0), (0.45, -0.3, 2.5), (-0.5, 0.35, 3.0), (0.2, 0.45, 1.8), beyond_centred_view]
    sphere = {"type": mujoco.mjtGeom.mjGEOM_SPHERE, "size": [radius, 0, 0]}
    frame, view = _render(k, [(list(p), sphere) for p in points])

    assert (view.fx, view.fy) == (pytest.approx(k.fx, rel=1e-6), pytest.approx(k.fy, rel=1e-6))
    np.testing.assert_allclose(
        view.shift_px, (k.cx + 0.5 - k.width / 2, k.cy + 0.5 - k.height / 2), atol=1e-4
    )
    for i, point in enumerate(np.array(points)):
        v, u = np.nonzero(frame.instances == i + 1)
        assert len(u) > 30, f"sphere {i} drew {len(u)} pixels"
        centroid = np.array([u.mean(), v.mean()])
        np.testing.assert_allclose(
            centroid, ellipse_centre(k, point, radius), atol=0.3, err_msg=f"sphere {i}"
        )
        assert np.abs(centroid - ellipse_centre(CENTRED, point, radius)).max() > 5
        assert frame.unoccluded[i + 1] == (len(u), False)


def _plane_box(normal: np.ndarray, thickness: float) -> dict:
    """A thin box geom whose +z face lies on the plane through its body's position with
    ``normal`` (OpenCV camera frame, pointing at the camera)."""
    from depotbench.sim.mujoco_env import mujoco

    x_axis = np.cross([0.0, 1.0, 0.0], normal)
    x_axis /= np.linalg.norm(x_axis)
    gl = np.diag([1.0, -1.0, -1.0])  # OpenCV's camera frame to MuJoCo's (and back)
    rotation = gl @ np.stack([x_axis, np.cross(normal, x_axis), normal], axis=1)
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, rotation.ravel())
    return {
        "type": mujoco.mjtGeom.mjGEOM_BOX,
        "size": [6.0, 6.0, thickness],
        "pos": list(gl @ (-normal * thickness)),
        "quat": list(quat),
    }


@pytest.mark.render
def test_a_tilted_planes_depth_is_its_ray_depth_at_every_pixel():
    """A plane n . p = d tilted both ways, seen through the skewed pinhole: the rendered
    z-depth at every pixel (u, v) is d / (n . ((u - cx) / fx, (v - cy) / fy, 1)); at the
    principal point it is the plane's z on the optical axis; and back-projecting every pixel
    with the intrinsics gives points whose fitted plane is the true one (with the centred
    camera's intrinsics the fit tilts by degrees)."""
    k = SKEWED
    normal = np.array([0.35, -0.25, -1.0])
    normal /= np.linalg.norm(normal)
    d = -2.2  # n points at the camera; the plane's nearest point is n d
    frame, _ = _render(k, [(list(normal * d), _plane_box(normal, 0.01))])
    depth = frame.depth.astype(np.float64)
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)

    def back_projected(c: Intrinsics) -> np.ndarray:
        return np.stack([(u - c.cx) / c.fx * depth, (v - c.cy) / c.fy * depth, depth], axis=-1).reshape(-1, 3)

    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], axis=-1)
    np.testing.assert_allclose(depth, d / (rays @ normal), rtol=1e-5)
    assert depth[int(k.cy), int(k.cx)] == pytest.approx(d / normal[2], rel=1e-5)

    def fitted_normal(points: np.ndarray) -> np.ndarray:
        centred = points - points.mean(axis=0)
        return np.linalg.svd(centred, full_matrices=False)[2][-1]

    points = back_projected(k)
    assert np.abs(points @ normal - d).max() < 1e-4
    assert abs(fitted_normal(points) @ normal) > math.cos(math.radians(0.01))
    assert abs(fitted_normal(back_projected(CENTRED)) @ normal) < math.cos(math.radians(1.0))


def _scenario(**changes) -> ScenarioSpec:
    """A 64x48 scene with nobody in it, its camera still: two frames render in a second."""
    spec = dataclasses.replace(
        default_scenario(frames=2), width=64, height=48, focal_px=52.5, actors=(), chairs=()
    )
    return dataclasses.replace(spec, camera=CameraSpec(motion="static"), **changes)


@pytest.mark.render
def test_a_generated_sequences_floor_back_projects_to_z_zero(tmp_path):
    """TUM fr3's camera shrunk to 64x48 (at_size) through the whole simulator: camera.yaml holds it,
    meta.json gives the spec back, and every pixel's depth back-projected with camera.yaml's
    intrinsics and the ground-truth pose lands on or above the floor (z = 0), a quarter or
    more of them on it to within 2 mm; with centred intrinsics the floor tilts to -1 cm."""
    from depotbench.sim.generate import generate
    from depotbench.sim.sequence import Sequence

    fr3 = TUM_FR3  # at_size scales pixel edges, not centres: c' = (c + 0.5) s - 0.5
    full = dataclasses.replace(
        _scenario(),
        width=640,
        height=480,
        focal_px=fr3["fx"],
        focal_y_px=fr3["fy"],
        principal_px=(320.1, 247.6),
    )
    spec = at_size(full, 64, 48)
    principal = ((fr3["cx"] + 0.5) * 0.1 - 0.5, (fr3["cy"] + 0.5) * 0.1 - 0.5)
    assert (spec.focal_px, spec.focal_y_px) == pytest.approx((53.54, 53.92), abs=1e-12)
    assert spec.principal_px == pytest.approx(principal, abs=1e-12)
    sequence = Sequence.open(generate(spec, tmp_path / "fr3", progress=False))
    k = sequence.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((53.54, 53.92, principal[0], principal[1]), abs=1e-9)
    assert spec_from_dict(sequence.meta["scenario"]) == spec

    depth = sequence.depth_m(0).astype(np.float64)
    pose = sequence.world_from_camera(0)
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)

    def heights(c: Intrinsics) -> np.ndarray:
        camera = np.stack([(u - c.cx) / c.fx * depth, (v - c.cy) / c.fy * depth, depth], axis=-1)
        return (camera[depth > 0] @ pose[:3, :3].T + pose[:3, 3])[:, 2]

    z = heights(k)
    assert z.min() > -2e-3
    assert np.mean(np.abs(z) < 2e-3) > 0.25
    centred = dataclasses.replace(k, fy=k.fx, cx=(k.width - 1) / 2, cy=(k.height - 1) / 2)
    assert heights(centred).min() < -1e-2


@pytest.mark.render
def test_a_scenario_without_fy_or_principal_point_keeps_its_fovy_camera():
    """Every scenario before (no fy, no principal point) compiles the same MuJoCo camera as
    before, a fovy camera whose intrinsics are the fovy formula's; meta.json without the new
    fields reads back as such a scenario."""
    spec = _scenario()
    fovy = 2 * math.degrees(math.atan((48 / 2) / 52.5))
    assert intrinsics_of(spec) == Intrinsics.from_fovy(fovy, 64, 48)
    assert camera_attributes(intrinsics_of(spec)) == {"fovy": Intrinsics.from_fovy(fovy, 64, 48).fovy_deg()}
    model = build_world(spec).model
    assert model.cam_sensorsize[0].tolist() == [0.0, 0.0]
    assert model.cam_fovy[0] == pytest.approx(fovy, abs=1e-12)
    stored = dataclasses.asdict(spec)
    del stored["focal_y_px"], stored["principal_px"]
    assert spec_from_dict(stored) == spec
    skewed = _scenario(focal_y_px=55.0, principal_px=(30.0, 20.0))
    assert intrinsics_of(skewed) == Intrinsics(52.5, 55.0, 30.0, 20.0, 64, 48)
    assert "sensor_size" in camera_attributes(intrinsics_of(skewed))


def test_tum_intrinsics_in_yaml_reach_the_spec():
    """A scenario's ``intrinsics: {fx, fy, cx, cy}`` become the spec's pinhole; a principal
    point given on one axis keeps the centre on the other."""
    scenario = to_scenario(parse_scenario({"name": "fr3", "intrinsics": TUM_FR3}, "fr3.yaml"))
    assert (scenario.focal_px, scenario.focal_y_px, scenario.principal_px) == (535.4, 539.2, (320.1, 247.6))
    assert intrinsics_of(scenario) == Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480)
    one_axis = to_scenario(parse_scenario({"name": "a", "intrinsics": {"cy": 250.0}}, "a.yaml"))
    assert (one_axis.focal_y_px, one_axis.principal_px) == (None, (319.5, 250.0))
    plain = to_scenario(parse_scenario({"name": "a"}, "a.yaml"))
    assert (plain.focal_y_px, plain.principal_px) == (None, None)


REFUSED = {
    "cx off the image": ({"principal_px": (64.0, 20.0)}, "principal_px[0]: 64 px lies off the image"),
    "cy off the image": ({"principal_px": (30.0, -0.6)}, "principal_px[1]: -0.6 px lies off the image"),
    "anamorphic": ({"focal_y_px": 150.0}, "focal_y_px: fy / fx = 2.86"),
    "fy too short": ({"focal_px": 1.0, "focal_y_px": 1.0}, "focal_px: 1 px gives a field of view"),
    "fy not finite": ({"focal_y_px": float("nan")}, "focal_y_px: must be a finite number"),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_an_impossible_pinhole_is_refused_naming_its_field(case):
    changes, message = REFUSED[case]
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        _scenario(**changes)


@pytest.mark.parametrize(
    ("intrinsics", "message"),
    [
        ({"cx": -3.0}, "intrinsics.cx: -3 px lies off the image"),
        ({"fx": 500, "fy": 1100}, "intrinsics.fy: fy / fx = 2.2"),
        ({"fy": 0.5}, "intrinsics.fy: 0.5 px gives a field of view"),
    ],
)
def test_an_impossible_pinhole_in_yaml_is_one_line_naming_the_field(intrinsics, message):
    with pytest.raises(InputError) as refused:
        parse_scenario({"name": "a", "intrinsics": intrinsics}, "a.yaml")
    assert message in str(refused.value) and "\n" not in str(refused.value)
