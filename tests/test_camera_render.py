"""The simulated camera (``insulator_rs.sim.camera_render``).

References: ``cv2.projectPoints`` for the per-pixel rays (they must project back
onto their pixel centres, 1e-6 px); the project's ``project_points`` for the
camera/LiDAR consistency (tolerance 1 px, because boxes are built from pixel-centre
rays and a point on an insulator's silhouette can fall in a pixel whose centre
ray misses it); pinhole geometry for occlusion (1 px).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from helpers.lidar_room import body_pose

from insulator_rs._core import CameraModel, project_points
from insulator_rs.sim.camera_render import Camera, Lighting, boxes_from_instance_image, pixel_rays
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.mesh import InstanceInfo, Mesh, box, plane
from insulator_rs.sim.towers import load_tower

SMALL = CameraModel(350.0, 350.0, 319.5, 239.5, 640, 480, dist=(-0.12, 0.03, 0.001, -0.001, 0.0))
PINHOLE = CameraModel(400.0, 400.0, 199.5, 149.5, 400, 300)


@pytest.mark.parametrize("model", [SMALL, PINHOLE], ids=["distorted", "pinhole (closed form)"])
def test_pixel_rays_project_back_onto_pixel_centres(model: CameraModel) -> None:
    rays = pixel_rays(model)
    assert rays.shape == (model.width * model.height, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    uv, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), model.camera_matrix(),
                              np.array(model.dist))
    u, v = np.meshgrid(np.arange(float(model.width)), np.arange(float(model.height)))
    np.testing.assert_allclose(uv.reshape(-1, 2), np.column_stack([u.ravel(), v.ravel()]), atol=1e-6)


def test_lidar_points_on_an_insulator_project_inside_its_box() -> None:
    """Tower A, camera and LiDAR on one hovering body 9 m from an insulator: every
    LiDAR point on an insulator that the camera also sees (unobstructed line of
    sight) projects, with ``project_points``, inside that insulator's box +- 1 px."""
    tower = load_tower("tower_a")
    mesh = tower.mesh
    target = tower.insulators[0]
    # Stand off 9 m across the line (x), 1 m below, looking back at the insulator.
    side = np.sign(target.center[0]) or 1.0
    T_w_b = body_pose(target.center + [9.0 * side, 0.0, -1.0], np.pi if side > 0 else 0.0)
    T_b_c = np.eye(4)
    T_b_c[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    T_b_c[:3, 3] = [0.1, 0.0, -0.05]
    T_b_l = np.eye(4)
    T_b_l[:3, 3] = [0.0, 0.0, 0.12]
    camera = Camera(SMALL, T_b_c)
    frame = camera.render(mesh, T_w_b, lighting=Lighting(noise_sigma=0.0), min_box_pixels=1)
    scan = Mid360(T_b_l, range_noise=0.0).scan(mesh, (T_w_b, T_w_b), 0.0, seed=4)
    T_c_l = np.linalg.inv(T_b_c) @ T_b_l
    insulator_ids = set(mesh.instance_ids_of_kind("insulator"))
    on = np.isin(scan.instance_id, list(insulator_ids))
    pts_l, ids = scan.points_l[on], scan.instance_id[on]
    # Line of sight from the camera to each point (nothing nearer than the point itself).
    cam_pos = frame.T_w_c[:3, 3]
    pts_w = scan.points_w[on]
    to_pt = pts_w - cam_pos
    dist = np.linalg.norm(to_pt, axis=1)
    seen = mesh.raycaster.cast(np.tile(cam_pos, (len(dist), 1)), to_pt, 1000.0)
    visible = (seen.distance > dist - 1e-3) & (seen.instance_id == ids)
    uv, valid = project_points(pts_l, T_c_l, SMALL)
    checked = 0
    for k in np.flatnonzero(visible & valid):
        box_k = frame.boxes.get(int(ids[k]))
        assert box_k is not None, f"insulator {ids[k]} seen by a LiDAR point has no box"
        x1, y1, x2, y2 = box_k
        u, v = uv[k]
        assert x1 - 1 <= u <= x2 + 1 and y1 - 1 <= v <= y2 + 1, (ids[k], (u, v), box_k)
        checked += 1
    assert checked >= 20, f"only {checked} visible insulator points: the test would mean little"
    assert len(frame.boxes) >= 2


def test_boxes_follow_occlusion() -> None:
    """An insulator-kind box spans x in [-1, 1] at 10 m; a tower-kind box covering x > 0
    at 5 m hides its right half: the GT box ends at the occluder's edge (pinhole,
    u = cx + f x / z), within 1 px. A fully hidden insulator gets no box."""
    ins = box([0, 0, 10], [2, 0.4, 0.2], instance_id=1, info=InstanceInfo("ins", "insulator"))
    hidden = box([1.5, 3, 12], [0.5, 0.5, 0.5], instance_id=2, info=InstanceInfo("hidden", "insulator"))
    occluder = box([1.5, 1.0, 5], [3.0, 6.0, 0.2], instance_id=3, info=InstanceInfo("steel", "tower"))
    mesh = Mesh.concatenate([ins, hidden, occluder])
    camera = Camera(PINHOLE, np.eye(4))  # C = B = W: looking along +z
    frame = camera.render(mesh, np.eye(4), lighting=Lighting(noise_sigma=0.0), min_box_pixels=1)
    assert set(frame.boxes) == {1}
    x1, y1, x2, y2 = frame.boxes[1]
    f, cx, cy = 400.0, 199.5, 149.5
    assert x1 == pytest.approx(cx + f * -1.0 / 9.9, abs=1.0)  # front face at z = 9.9
    assert x2 == pytest.approx(cx + f * 0.0 / 4.9, abs=1.0)  # occluder's edge x = 0 at z = 4.9
    assert y1 == pytest.approx(cy + f * -0.2 / 9.9, abs=1.0)
    assert y2 == pytest.approx(cy + f * 0.2 / 9.9, abs=1.0)
    assert frame.visible_pixels[1] == int(np.sum(frame.instance_id == 1))


def test_boxes_from_instance_image_uses_pixel_edges_and_min_pixels() -> None:
    img = np.full((10, 12), -1, np.int32)
    img[2:5, 3:7] = 4
    img[8, 8] = 5
    boxes, counts = boxes_from_instance_image(img, [4, 5, 6], min_pixels=2)
    assert boxes == {4: (2.5, 1.5, 6.5, 4.5)} and counts == {4: 12}
    with pytest.raises(ValueError, match="instance_id"):
        boxes_from_instance_image(img[0], [4])


def test_lighting_time_of_day_and_haze() -> None:
    """Noon is brighter than 07:00; dense haze pulls a far grey wall toward the horizon colour."""
    wall = plane([0, 0, 60], [0, 0, -1], (200, 200), instance_id=0, info=InstanceInfo("w", "tower", color=(0.5, 0.5, 0.5)))
    ground = plane([0, -20, 0], [0, 1, 0], (500, 500), instance_id=1, info=InstanceInfo("g", "ground"))
    mesh = Mesh.concatenate([wall, ground])
    camera = Camera(CameraModel(50.0, 50.0, 15.5, 11.5, 32, 24), np.eye(4))
    noon = camera.render(mesh, np.eye(4), lighting=Lighting.at_time_of_day(12, noise_sigma=0, haze_density=0))
    morning = camera.render(mesh, np.eye(4), lighting=Lighting.at_time_of_day(7, noise_sigma=0, haze_density=0))
    assert noon.rgb.mean() > morning.rgb.mean() + 5
    light = Lighting(noise_sigma=0, haze_density=0.2)
    fog = camera.render(mesh, np.eye(4), lighting=light)
    horizon = np.round(255 * np.array(light.sky_horizon) ** (1 / 2.2))
    assert np.abs(fog.rgb[fog.instance_id == 0].astype(float) - horizon).max() <= 1
    sun = np.array(Lighting.at_time_of_day(12).sun_direction)
    assert sun[1] < 0 and np.degrees(np.arcsin(sun[2])) == pytest.approx(60, abs=1e-9)
    with pytest.raises(ValueError, match="hour"):
        Lighting.at_time_of_day(23)


def test_render_is_deterministic_under_a_seed() -> None:
    mesh = Mesh.concatenate([plane([0, 0, 0], [0, 0, 1], (100, 100), instance_id=0),
                             box([5, 0, 2], [1, 1, 4], instance_id=1)])
    camera = Camera(PINHOLE)
    T = body_pose([0, 0, 2], 0.0)
    a = camera.render(mesh, T, seed=3)
    b = camera.render(mesh, T, seed=3)
    c = camera.render(mesh, T, seed=4)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.instance_id, c.instance_id)
    assert np.any(a.rgb != c.rgb)


def test_bad_input_gets_clear_errors() -> None:
    mesh = Mesh.concatenate([plane([0, 0, 0], [0, 0, 1], (100, 100), instance_id=0, info=InstanceInfo("g", "ground")),
                             box([5, 0, 2], [1, 1, 4], instance_id=1, info=InstanceInfo("pylon", "tower"))])
    camera = Camera(PINHOLE)
    with pytest.raises(ValueError, match="inside geometry.*pylon"):
        camera.render(mesh, body_pose([5, 0, 2], 0.0))
    with pytest.raises(ValueError, match="inside geometry"):
        camera.render(mesh, body_pose([0, 0, -3], 0.0))
    with pytest.raises(ValueError, match="T_w_b"):
        camera.render(mesh, np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="T_b_c"):
        Camera(PINHOLE, np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(TypeError, match="model"):
        Camera("wide")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="width"):
        mesh.raycaster.render(np.eye(4), np.zeros((0, 3)), 0, 10, mesh.albedo_table())
