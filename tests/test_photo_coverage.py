"""The ground-truth photo check (evaluation/photo_coverage.py): a string covered by photos at
>= 60 % of the long side and <= 2 mm/px, through each photo's own pose and intrinsics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from insulator_rs.evaluation.photo_coverage import photo_coverage, string_in_photo, _camera


@dataclass
class Truth:
    instance_id: int
    center: np.ndarray
    axis: np.ndarray
    length: float


ZOOM = {"fx": 8000.0, "fy": 8000.0, "cx": 2000.0, "cy": 1500.0, "width": 4000, "height": 3000, "dist": [0.0] * 5}
SIM = {"fx": 700.0, "fy": 700.0, "cx": 640.0, "cy": 480.0, "width": 1280, "height": 960, "dist": [0.0] * 5}
STRING = Truth(7, np.array([3.0, 0.0, 15.0]), np.array([1.0, 0.0, 0.0]), 1.2)  # horizontal (strain) string


def _looking_north_at(target: np.ndarray, distance: float) -> np.ndarray:
    """T_w_c of a level camera ``distance`` m south of ``target``, looking north (optical z = +y W,
    x right = +x W, y down = -z W)."""
    T = np.eye(4)
    T[:3, :3] = np.column_stack([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    T[:3, 3] = target - np.array([0.0, distance, 0.0])
    return T


def test_a_zoomed_shot_covers_the_string_and_the_wide_one_does_not():
    # 2800 px of 4000 (70 %) at 3.43 m: 0.43 mm/px
    near = {"file": "a.jpg", "T_w_c": _looking_north_at(STRING.center, 8000 * 1.2 / 2800).tolist(), "camera": ZOOM}
    wide = {"file": "b.jpg", "T_w_c": _looking_north_at(STRING.center, 6.0).tolist(), "camera": SIM}
    out = photo_coverage({"photos": [near, wide]}, [STRING])
    row = out["insulators"][0]
    assert out["insulators_covered"] == 1 and row["covered"] and row["qualifying_photos"] == 1
    a, b = row["photos"]
    assert a["span_share"] == pytest.approx(0.70, abs=1e-3) and a["gsd_mm"] == pytest.approx(3.4286 / 8, rel=1e-3)
    assert b["span_share"] == pytest.approx(700 * 1.2 / 6 / 1280, rel=1e-3)  # 10.9 %, as today's photos
    assert b["gsd_mm"] == pytest.approx(6000 / 700, rel=1e-3) and not b["qualifies"]  # 8.6 mm/px


def test_two_overlapping_tiles_cover_a_long_string_one_does_not():
    long = Truth(1, np.array([0.0, 0.0, 10.0]), np.array([1.0, 0.0, 0.0]), 4.0)
    d = 8000 * 2.4 / 3600  # each tile sees 2.4 m of the string over 3600 px (90 % of 4000)
    left = {"T_w_c": _looking_north_at(long.center - [0.9, 0, 0], d).tolist(), "camera": ZOOM}
    right = {"T_w_c": _looking_north_at(long.center + [0.9, 0, 0], d).tolist(), "camera": ZOOM}
    one = photo_coverage({"photos": [left]}, [long])["insulators"][0]
    both = photo_coverage({"photos": [left, right]}, [long])["insulators"][0]
    assert one["covered_fraction"] == pytest.approx(0.6, abs=0.01) and not one["covered"]
    assert both["covered"] and both["covered_fraction"] == pytest.approx(1.0, abs=1e-9)


def test_behind_the_camera_and_out_of_frame_see_nothing():
    back = _looking_north_at(STRING.center, -3.0)  # the string is behind
    fig = string_in_photo(_camera(ZOOM), back, STRING.center, STRING.axis, STRING.length)
    assert fig["visible"] is None and fig["span_share"] == 0.0


def test_pose_from_position_yaw_and_T_b_c_as_the_flight_records_it():
    """A record without T_w_c (today's flights): the pose from position, yaw and T_b_c."""
    from insulator_rs.evaluation.photo_coverage import photo_pose

    T_b_c = np.array([[0.0, 0, 1, 0.1], [-1, 0, 0, 0], [0, -1, 0, -0.05], [0, 0, 0, 1]])
    rec = {"position": [1.0, 2.0, 3.0], "yaw": np.pi / 2, "T_b_c": T_b_c.tolist()}
    T = photo_pose(rec)
    assert np.allclose(T[:3, 2], [0, 1, 0])  # looking north (yaw 90 deg in ENU)
    assert np.allclose(T[:3, 3], [1.0, 2.1, 2.95])


# -- whole in frame and visible: the scorer's answer, from the same projection ------------------------------------


def _look_at(position: np.ndarray, target: np.ndarray) -> np.ndarray:
    """T_w_c of a camera at ``position`` looking at ``target`` (optical: x right, y down, z ahead)."""
    z = (target - position) / np.linalg.norm(target - position)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = position
    return T


def _cv2_reference(cam: dict, T_w_c: np.ndarray, pts: np.ndarray) -> tuple[bool, bool]:
    """(any point in the frame, all points in the frame) by cv2.projectPoints, with the depth
    taken in the camera frame by hand: the independent reference for string_in_photo."""
    import cv2

    T_c_w = np.linalg.inv(T_w_c)
    K = np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1.0]])
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    uv, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), rvec, T_c_w[:3, 3], K, np.asarray(cam["dist"], dtype=np.float64))
    uv = uv.reshape(-1, 2)
    depth = (pts @ T_c_w[:3, :3].T + T_c_w[:3, 3])[:, 2]
    inside = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam["width"]) & (uv[:, 1] >= 0) & (uv[:, 1] < cam["height"])
    return bool(inside.any()), bool(inside.all())


def test_whole_in_frame_and_visible_match_cv2_project_points():
    """Reference: cv2.projectPoints of the same string (its axis and its end sheds' rims), on 300
    random camera poses about a tilted string with a distorted lens; the answers must be equal
    (both measure the same points: no tolerance), with both outcomes of each well represented."""
    from insulator_rs.evaluation.photo_coverage import SAMPLES
    from insulator_rs.perception.photo_quality import RIM_POINTS

    rng = np.random.default_rng(7)
    cam = {**SIM, "dist": [-0.08, 0.02, 0.0005, -0.0004, 0.0]}
    center, length, radius = np.array([2.0, -1.0, 12.0]), 1.6, 0.13
    axis = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
    e1 = np.cross(axis, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    a = np.linspace(0, 2 * np.pi, RIM_POINTS, endpoint=False)[:, None]
    ring = radius * (np.cos(a) * e1 + np.sin(a) * e2)
    pts = np.vstack([center + (np.linspace(0, 1, SAMPLES)[:, None] - 0.5) * length * axis,
                     center - 0.5 * length * axis + ring, center + 0.5 * length * axis + ring])
    outcomes = []
    for _ in range(300):
        direction = rng.normal(size=3)
        direction[2] *= 0.3
        position = center + rng.uniform(0.8, 6.0) * direction / np.linalg.norm(direction)
        T_w_c = _look_at(position, center + rng.normal(scale=0.8, size=3))
        fig = string_in_photo(_camera(cam), T_w_c, center, axis, length, radius=radius)
        got = (fig["visible"] is not None, fig["whole_in_frame"])
        axis_any, _ = _cv2_reference(cam, T_w_c, pts[:SAMPLES])  # visible: a point of its axis in the frame
        _, all_in = _cv2_reference(cam, T_w_c, pts)
        assert got == (axis_any, all_in)
        outcomes.append(got)
    assert outcomes.count((True, True)) > 30 and outcomes.count((True, False)) > 30
    assert outcomes.count((False, False)) > 10


def test_the_projection_answers_as_the_old_render_did_on_a_real_tower():
    """The old scorer rendered each photo and read the string's box: visible when the box is
    there, whole when it touches no border. Rendered here at 320x240 (cheap) from views of tower
    B's strings (near: cut; far: whole; aimed away: not seen); the projection must say the same
    for every view the tower hides no part of the string in."""
    from insulator_rs.sim.camera_render import Camera
    from insulator_rs.sim.towers import load_tower

    tower = load_tower("tower_b")
    cam = {"fx": 260.0, "fy": 260.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240, "dist": [0.0] * 5}
    model = _camera(cam)
    renderer = Camera(model, np.eye(4))
    compared = []
    for ins in tower.insulators:
        out = np.array([ins.center[0], ins.center[1], 0.0])
        out = out / np.linalg.norm(out)  # away from the tower's axis, level
        for distance, aim in ((0.9, np.zeros(3)), (2.5, np.zeros(3)), (6.0, np.zeros(3)),
                              (6.0, np.array([0.0, 0.0, 0.8])), (4.0, 5.0 * np.cross(out, [0, 0, 1.0]))):
            T_w_c = _look_at(ins.center + distance * out + [0, 0, 0.3], ins.center + aim)
            fig = string_in_photo(model, T_w_c, ins.center, ins.axis, ins.length, radius=ins.radius)
            frame = renderer.render(tower.mesh, T_w_c)
            box = frame.boxes.get(ins.instance_id)
            rendered = (box is not None,
                        box is not None and box[0] > 0 and box[1] > 0 and box[2] < model.width and box[3] < model.height)
            compared.append(((fig["visible"] is not None, fig["whole_in_frame"]), rendered))
    assert len(compared) >= 20
    agree = [p == r for p, r in compared]
    assert all(agree), [c for c, ok in zip(compared, agree) if not ok]
    assert {p for p, _ in compared} >= {(True, True), (True, False), (False, False)}
