"""The inspection camera (rig ``[inspection_camera]``), the shots framed for it
(planning/framing.py, planning/waypoints.py) and its gimbal (flight/gimbal.py), checked against
an independent reference: cv2.projectPoints of the string's ends through each shot's own camera
pose and intrinsics, and cv2.Rodrigues for the body's tilt."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from insulator_rs.exceptions import ConfigError
from insulator_rs.flight.gimbal import aim_at
from insulator_rs.geodesy import LineFrame
from insulator_rs.inspection_camera import GimbalLimits
from insulator_rs.planning.framing import MAX_FILL, MIN_FILL
from insulator_rs.planning.safety import safety_volumes
from insulator_rs.planning.waypoints import PUSH_CLEARANCE, inspection_waypoints
from insulator_rs.rig import load_rig, scaled_camera, simulator_rig
from insulator_rs.poses import pose_from_yaw
from helpers.rig_files import T_B_C, T_B_L, write_opencv_calibration, write_zoom_rig

def _K(cam) -> np.ndarray:
    return np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]])


def project(T_w_c: np.ndarray, cam, points_w: np.ndarray) -> np.ndarray:
    """Pixels of W points through the camera at ``T_w_c`` with intrinsics ``cam``: cv2.projectPoints."""
    T_c_w = np.linalg.inv(T_w_c)
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    uv, _ = cv2.projectPoints(np.asarray(points_w, dtype=np.float64).reshape(-1, 1, 3), rvec, T_c_w[:3, 3],
                              _K(cam), np.asarray(cam.dist, dtype=np.float64))
    return uv.reshape(-1, 2)


def test_the_simulator_rig_has_a_12_mp_zoom_on_a_gimbal_and_an_old_rig_falls_back(tmp_path):
    cam = simulator_rig().inspection_camera()
    assert cam.dedicated and cam.zoom and (cam.camera.width, cam.camera.height) == (4000, 3000)
    assert cam.focal_px == pytest.approx((4.5 / 1.55e-3, 45.0 / 1.55e-3), rel=1e-6)  # 4.5-45 mm, 1.55 um
    assert cam.gimbal.pitch == pytest.approx((math.radians(-90), math.radians(30)))
    assert cam.focal_length_mm(cam.focal_px[1]) == pytest.approx(45.0)
    assert cam.at_focal(10_000.0).fx == pytest.approx(10_000.0) and cam.at_focal(10_000.0).cx == cam.camera.cx
    with pytest.raises(ValueError, match="focal_px"):
        cam.at_focal(1000.0)
    write_opencv_calibration(tmp_path / "cam.yaml")
    old = tmp_path / "old.toml"
    old.write_text(f'[camera]\ncalibration = "cam.yaml"\nT_b_c = {T_B_C}\n\n[lidar]\nT_b_l = {T_B_L}\n')
    rig = load_rig(old)
    assert rig.inspection is None
    fallback = rig.inspection_camera()
    assert not fallback.dedicated and not fallback.zoom and fallback.camera is rig.camera
    np.testing.assert_array_equal(fallback.T_b_c, rig.T_b_c)


def test_a_rig_gives_the_zoom_in_px_or_a_fixed_lens(tmp_path):
    rig = load_rig(write_zoom_rig(tmp_path, "focal_length_px = [2903.2258, 14000.0]\ngimbal_yaw_deg = [-20, 20]\n"))
    assert rig.inspection.focal_px == pytest.approx((2903.2258, 14000.0))
    assert rig.inspection.gimbal.yaw == pytest.approx((math.radians(-20), math.radians(20)))
    fixed = load_rig(write_zoom_rig(tmp_path, 'make = "GoPro"\nmodel = "HERO12 Black"\n'))
    assert fixed.inspection.focal_px == (2903.2258, 2903.2258) and not fixed.inspection.zoom
    assert fixed.inspection.exif(2903.2258) == {"make": "GoPro", "model": "HERO12 Black", "focal_length_mm": None}


@pytest.mark.parametrize("table, field", [
    ("focal_length_mm = [4.5, 45.0]\n", "inspection_camera.pixel_pitch_um"),
    ("focal_length_px = [2000.0, 20000.0]\n", "inspection_camera.focal_length_px"),  # not the widest's
    ("focal_length_px = [2903.2, 2000.0]\n", "inspection_camera.focal_length_px"),  # max < min
    ("focal_length_px = [2903.2, 9000.0]\nfocal_length_mm = [4.5, 9.0]\n", "inspection_camera.focal_length_mm"),
    ("gimbal_pitch_deg = [30, -90]\n", "inspection_camera.gimbal_pitch_deg"),
    ("gimbal_yaw_deg = 15\n", "inspection_camera.gimbal_yaw_deg"),
    ("zoom = 10\n", "inspection_camera.zoom"),
    ('model = ""\n', "inspection_camera.model"),
    ("T_b_c = [[1, 0, 0]]\n", "inspection_camera.T_b_c"),
])
def test_bad_inspection_camera_tables_name_the_field(tmp_path, table, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_rig(write_zoom_rig(tmp_path, table))


def test_a_missing_zoom_calibration_is_named(tmp_path):
    rig = write_zoom_rig(tmp_path, "")
    (tmp_path / "zoom.yaml").unlink()
    with pytest.raises(ConfigError, match=r"inspection_camera\.calibration"):
        load_rig(rig)


LINE = LineFrame(np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]), (np.array([0.0, 150.0, 0.0]),))
VOLUMES = safety_volumes(LINE, max_width=9.0, max_height=28.5, margin=2.0)


def _shot_T_w_c(wp, cam) -> np.ndarray:
    """The camera pose of a waypoint, as the flight aims it: a level body at the waypoint's yaw
    (with a 2 deg heading error the gimbal takes up), the gimbal aimed at the target."""
    T_w_b = pose_from_yaw(wp.position, wp.yaw + math.radians(2.0))
    _, _, T_b_c = aim_at(T_w_b, cam.T_b_c, wp.target, cam.gimbal)
    return T_w_b @ T_b_c


def _part(T_w_c, model, center, axis, length, samples=401):
    """The string's part in the frame: (span over the long side, mm/px at its farthest visible
    point, covered interval in [0, 1]), from cv2.projectPoints of points along the axis."""
    t = np.linspace(0.0, 1.0, samples)
    pts = center + (t[:, None] - 0.5) * length * axis
    uv = project(T_w_c, model, pts)
    depth = (pts - T_w_c[:3, 3]) @ T_w_c[:3, 2]
    inside = (depth > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= model.width - 0.5) & \
        (uv[:, 1] >= -0.5) & (uv[:, 1] <= model.height - 0.5)
    idx = np.flatnonzero(inside)
    a, b = idx[0], idx[-1]
    span = float(np.linalg.norm(uv[b] - uv[a])) / max(model.width, model.height)
    return span, 1000.0 * float(depth[inside].max()) / model.fx, (float(t[a]), float(t[b]))


@pytest.mark.parametrize("center, axis, length, tiles", [
    ((3.6, -2.7, 16.0), (0.0, 0.0, 1.0), 1.5, 1),   # tower B's suspension string, hanging
    ((4.0, 3.0, 20.0), (0.0, 0.0, 1.0), 2.2, 1),    # tower A's
    ((6.0, 0.0, 22.0), (0.0, 1.0, 0.0), 2.0, 1),    # a strain string along the line
    ((6.0, 0.0, 22.0), (0.0, 1.0, 0.0), 9.0, 2),    # too long for one shot at 2 mm/px: tiles
])
def test_framed_shots_fill_the_long_side_at_2_mm_per_px_by_cv2(center, axis, length, tiles):
    cam = simulator_rig().inspection_camera()
    c, u = np.array(center), np.array(axis)
    wps = inspection_waypoints(c, u, insulator_id=1, line=LINE, volumes=VOLUMES, count=2, inspection_distance=6.0,
                               insulator_length=length, fov=1.0, inspection=cam)
    assert len(wps) == 2 * tiles and {w.tiles for w in wps} == {tiles}
    assert VOLUMES.points_clear(np.array([w.position for w in wps]), inflate=PUSH_CLEARANCE).all()
    for fan in (wps[:tiles], wps[tiles:]):
        covered = []
        for wp in fan:
            model = cam.at_focal(wp.focal_px)
            assert np.linalg.norm(wp.position - wp.target) >= 6.0 - 1e-9  # the safe distance
            span, gsd, interval = _part(_shot_T_w_c(wp, cam), model, c, u, length)
            assert gsd <= 2.0 and gsd == pytest.approx(wp.planned_gsd_mm, rel=0.02)
            if tiles == 1:
                assert MIN_FILL <= span <= MAX_FILL and interval == (0.0, 1.0)
            else:
                assert span >= MIN_FILL  # the part a tile holds runs across the frame
            covered.append(interval)
        covered.sort()
        assert covered[0][0] == 0.0 and covered[-1][1] == 1.0
        assert all(b[0] < a[1] for a, b in zip(covered, covered[1:]))  # tiles overlap: no gap


def test_the_gimbal_keeps_the_target_at_the_centre_while_the_body_tilts():
    """Body rolled 12 deg, pitched 9 deg forward, heading 4 deg off the target: the gimballed
    camera still sees the target at the principal point and the horizon level (cv2)."""
    cam = simulator_rig().inspection_camera()
    target = np.array([3.0, 8.0, 14.0])
    T_w_b = pose_from_yaw(np.array([3.0, 1.0, 13.0]), math.radians(90.0 + 4.0))
    tilt, _ = cv2.Rodrigues(np.array([math.radians(12.0), math.radians(9.0), 0.0]))
    T_w_b[:3, :3] = T_w_b[:3, :3] @ tilt
    pitch, yaw, T_b_c = aim_at(T_w_b, cam.T_b_c, target, cam.gimbal)
    T_w_c = T_w_b @ T_b_c
    model = cam.at_focal(12_000.0)
    uv = project(T_w_c, model, target[None])[0]
    assert uv == pytest.approx([model.cx, model.cy], abs=1e-6)
    heading = math.atan2(T_w_b[1, 0], T_w_b[0, 0])  # the tilted body's x axis seen from above
    assert heading + yaw == pytest.approx(math.radians(90.0), abs=1e-9)  # north, at the target
    assert pitch == pytest.approx(math.atan2(1, 7), abs=1e-9)
    assert abs(T_w_c[2, 0]) < 1e-12  # the image x axis stays horizontal: roll stabilised
    # beyond the gimbal's yaw range (30 deg) the limit holds and the target leaves the centre
    T_far = pose_from_yaw(np.array([3.0, 1.0, 13.0]), math.radians(90.0 + 45.0))
    _, yaw_far, _ = aim_at(T_far, cam.T_b_c, target, cam.gimbal)
    assert yaw_far == pytest.approx(math.radians(-30.0))
    assert GimbalLimits((-1.0, 0.5), (0.0, 0.0)).clamp(0.8, 0.2) == (0.5, 0.0)


@pytest.mark.slow
def test_the_simulator_renders_the_zoom_at_the_photo_scale(tmp_path):
    """A photo at 3.72x zoom rendered at scale 0.2: the frame's intrinsics are the zoom's scaled
    (800x600), and the string's rendered pixels match cv2.projectPoints of its true ends."""
    from insulator_rs.sim.sensors import SimulatedSensors
    from insulator_rs.sim.towers import load_tower

    tower = load_tower(Path(simulator_rig().source).parents[1] / "scenes" / "tower_b.toml")
    rig = simulator_rig()
    cam = rig.inspection_camera()
    truth = tower.insulators[0]
    T_w_b = pose_from_yaw(truth.center + np.array([6.0 * np.sign(truth.center[0]), 0.0, 0.0]),
                          0.0 if truth.center[0] < 0 else math.pi)
    sensors = SimulatedSensors(tower.mesh, lambda t: T_w_b, rig, photo_scale=0.2)
    _, _, T_b_c = aim_at(T_w_b, cam.T_b_c, truth.center, cam.gimbal)
    zoom = cam.at_focal(10_800.0)
    frame = sensors.photo(0.0, T_b_c, camera=zoom)
    expect = scaled_camera(zoom, 0.2)
    assert (frame.camera.width, frame.camera.height) == (800, 600) and frame.camera.fx == pytest.approx(expect.fx)
    assert frame.image.shape == (600, 800, 3)
    # the same camera's instance image: the string's pixels where cv2 puts its true ends
    from insulator_rs.sim.camera_render import Camera

    rendered = Camera(frame.camera, T_b_c).render(tower.mesh, T_w_b)
    x1, y1, x2, y2 = rendered.boxes[truth.instance_id]
    ends = project(T_w_b @ T_b_c, frame.camera, np.stack([truth.center - 0.5 * truth.length * truth.axis,
                                                          truth.center + 0.5 * truth.length * truth.axis]))
    assert x1 < ends[:, 0].min() and ends[:, 0].max() < x2  # the sheds are wider than the axis
    # the box holds the shed stack and its fittings (0.25 m each end at most)
    assert y1 <= ends[:, 1].min() + 1 and y2 >= ends[:, 1].max() - 1
    assert y2 - y1 <= (1.5 + 2 * 0.25) * expect.fy / 6.0 + 2
    assert abs(ends[1, 1] - ends[0, 1]) == pytest.approx(1.5 * expect.fy / 6.0, rel=1e-3)


@pytest.mark.slow
def test_a_rig_without_an_inspection_camera_flies_as_before(tmp_path):
    """The small scene with the simulator rig less its [inspection_camera]: the detection camera
    takes the photos (its 1280x960 at photo scale 0.2, fixed lens, no zoom in the records, its
    model in the EXIF), as every rig flew before there was one (the tower tests fly the zoom)."""
    import json

    from PIL import Image

    from insulator_rs.app.cli import main
    from insulator_rs.rig import RIGS_DIR
    from helpers.flights import ARGS, small_scene

    scene, mission = small_scene(tmp_path)
    text = (RIGS_DIR / "simulator.toml").read_text()
    (tmp_path / "old_rig.toml").write_text(text[:text.index("[inspection_camera]")] + text[text.index("[lidar]"):])
    (tmp_path / "simulator_camera.yaml").write_text((RIGS_DIR / "simulator_camera.yaml").read_text())
    m = mission.read_text()
    assert 'rig = "simulator"' in m
    mission.write_text(m.replace('rig = "simulator"', 'rig = "old_rig.toml"'))
    out = tmp_path / "report"
    assert main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS]) == 0
    photos = json.loads((out / "summary.json").read_text())["photos"]
    assert photos and all((p["camera"]["width"], p["camera"]["height"]) == (256, 192) for p in photos)
    assert all("focal_length_px" not in p and p["camera"]["fx"] == pytest.approx(140.0) for p in photos)
    exif = Image.open(out / photos[0]["file"]).getexif()
    assert exif[0x0110] == "simulated camera"


def _write_cv_calibration(path: Path, fx: float, fy: float, cx: float, cy: float, dist: list[float],
                          size: tuple[int, int] = (4000, 3000)) -> None:
    """An OpenCV FileStorage calibration written by cv2 itself (the rig reads it back)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", size[0])
    fs.write("image_height", size[1])
    fs.write("camera_matrix", np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]))
    fs.write("distortion_coefficients", np.array([dist]))
    fs.release()


# The widest step is the simulator's (2903.2 px, no distortion); two more steps, as a zoom lens's
# calibration gives them: the principal point wandering a few pixels, the distortion shrinking.
STEPS = [(7800.0, 7790.0, 2004.0, 1496.0, [-0.04, 0.01, 0.0, 0.0, 0.0]),
         (14000.0, 13990.0, 2010.0, 1490.0, [-0.01, 0.002, 0.0, 0.0, 0.0])]


def _stepped_rig(tmp_path: Path, steps=STEPS, extra: str = "") -> Path:
    names = []
    for i, (fx, fy, cx, cy, dist) in enumerate(steps):
        _write_cv_calibration(tmp_path / f"step{i}.yaml", fx, fy, cx, cy, dist)
        names.append(f'"step{i}.yaml"')
    return write_zoom_rig(tmp_path, f"focal_length_px = [2903.2258, 14000.0]\nzoom_calibrations = [{', '.join(names)}]\n"
                          + extra)


def test_a_calibrated_zoom_step_gives_its_own_intrinsics_and_between_steps_they_are_interpolated(tmp_path):
    """Reference: each step's calibration as written by cv2, and numpy.interp over the steps' mean
    focal lengths for every intrinsic between them."""
    cam = load_rig(_stepped_rig(tmp_path)).inspection
    wide = cam.camera
    table = [(wide.fx, wide.fy, wide.cx, wide.cy, list(wide.dist) + [0.0] * (5 - len(wide.dist))), *STEPS]
    focals = np.array([0.5 * (s[0] + s[1]) for s in table])
    for f, step in zip(focals, table):  # at a calibrated step: that calibration
        k = cam.at_focal(float(f))
        assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx(step[:4], rel=1e-12)
        np.testing.assert_allclose(list(k.dist)[:5], step[4], atol=1e-15)
    for f in (4000.0, 5352.0, 9000.0, 13_500.0):
        k = cam.at_focal(f)
        assert 0.5 * (k.fx + k.fy) == pytest.approx(f, rel=1e-12)
        for j, name in ((2, "cx"), (3, "cy")):
            assert getattr(k, name) == pytest.approx(np.interp(f, focals, [s[j] for s in table]), rel=1e-12)
        aspect = np.interp(f, focals, [s[0] for s in table]) / np.interp(f, focals, [s[1] for s in table])
        assert k.fx / k.fy == pytest.approx(aspect, rel=1e-12)
        for d in range(5):
            assert list(k.dist)[d] == pytest.approx(np.interp(f, focals, [s[4][d] for s in table]), abs=1e-15)


def test_without_zoom_steps_the_widest_calibration_is_scaled(tmp_path):
    cam = load_rig(write_zoom_rig(tmp_path, "focal_length_px = [2903.2258, 14000.0]\n")).inspection
    assert cam.zoom_steps == ()
    k = cam.at_focal(9000.0)
    assert k.fx == pytest.approx(9000.0 * cam.camera.fx / (0.5 * (cam.camera.fx + cam.camera.fy)))
    assert (k.cx, k.cy) == (cam.camera.cx, cam.camera.cy)


@pytest.mark.parametrize("steps, extra, message", [
    ([STEPS[1], STEPS[0]], "", r"zoom_calibrations\[1\].*not longer than"),  # out of order
    ([(20000.0, 20000.0, 2000.0, 1500.0, [0.0] * 5)], "", r"zoom_calibrations\[0\].*past the zoom"),
])
def test_bad_zoom_steps_are_named(tmp_path, steps, extra, message):
    with pytest.raises(ConfigError, match=message):
        load_rig(_stepped_rig(tmp_path, steps, extra))


def test_a_zoom_step_of_another_image_size_is_named(tmp_path):
    rig = _stepped_rig(tmp_path)
    _write_cv_calibration(tmp_path / "step1.yaml", *STEPS[1][:4], STEPS[1][4], size=(1920, 1080))
    with pytest.raises(ConfigError, match=r"zoom_calibrations\[1\].*1920x1080"):
        load_rig(rig)
    bad = write_zoom_rig(tmp_path, 'focal_length_px = [2903.2258, 14000.0]\nzoom_calibrations = "step0.yaml"\n')
    with pytest.raises(ConfigError, match=r"inspection_camera\.zoom_calibrations: expected a list"):
        load_rig(bad)
