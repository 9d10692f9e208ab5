"""Inspection photo figures (perception/photo_quality) and GSD-aware framing (planning/waypoints)
against hand-computed pinhole figures (tolerance 1e-9 relative unless stated)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.perception.photo_quality import MAX_GSD_MM, gsd_distance, photo_quality
from insulator_rs.planning.waypoints import FILL_FRACTION, framing_distance

# 1000 px focal length, 1280 x 960, principal point at the centre.
CAM = ir.CameraModel(1000.0, 1000.0, 639.5, 479.5, 1280, 960)
# Camera at the W origin looking along W's +x (optical z = W x, optical x = -W y, optical y = -W z).
T_C_W = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0, 0, 0, 1.0]])


def test_square_on_string_by_hand():
    """A 2 m string, 0.2 m sheds, horizontal across the view 4 m ahead: GSD = 4 m / 1000 px =
    4 mm/px. Its box: the end rims' nearest points (3.9 m deep, 1 m aside) give 2 x 1000 / 3.9 =
    512.8 px across; the rims' tops and bottoms (0.1 m at ~4 m) about 50 px high (within 2 %):
    whole in frame. At 0.5 m/s with 1/500 s: 1 mm smear = 0.25 px, sharp."""
    q = photo_quality(CAM, T_C_W, np.array([4.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), length=2.0,
                      diameter=0.2, speed=0.5, exposure=1 / 500)
    assert q.gsd_mm_px == pytest.approx(4.0, rel=1e-9)
    assert q.whole_in_frame and q.blur_within_limit
    width = 2 * 1000 / 3.9
    assert q.span_share == pytest.approx(width / 1280, rel=1e-9)
    assert q.frame_share == pytest.approx(width * 50 / (1280 * 960), rel=0.02)
    assert q.motion_blur_px == pytest.approx(0.25, rel=1e-9)
    assert q.gsd_mm_px > MAX_GSD_MM  # 4 mm/px: coarser than a defect inspection needs


def test_fit_blurred_cut_and_behind():
    """At 1.8 m the same string gives 1.8 mm/px and 1111 px + rims: whole, fit. At 1.2 m its ends
    leave the 1280 px frame. At 3 m/s, 1/100 s and 1.8 mm/px the smear is 16.7 px: not sharp.
    Behind the camera: infinite GSD, not whole."""
    c, u = np.array([1.8, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    q = photo_quality(CAM, T_C_W, c, u, length=2.0, diameter=0.2)
    assert q.gsd_mm_px == pytest.approx(1.8) and q.gsd_mm_px <= MAX_GSD_MM and q.whole_in_frame
    assert not photo_quality(CAM, T_C_W, np.array([1.2, 0.0, 0.0]), u, length=2.0).whole_in_frame
    blurred = photo_quality(CAM, T_C_W, c, u, length=2.0, speed=3.0, exposure=0.01)
    assert blurred.motion_blur_px == pytest.approx(3.0 * 0.01 / 0.0018) and not blurred.blur_within_limit
    behind = photo_quality(CAM, T_C_W, np.array([-4.0, 0.0, 0.0]), u, length=2.0)
    assert math.isinf(behind.gsd_mm_px) and not behind.whole_in_frame


def test_gsd_is_taken_at_the_farther_end():
    """A string tilted 30 deg towards the camera's axis: its far end lies 4 + sin(30) m deep:
    GSD 4.5 mm/px."""
    u = np.array([math.sin(math.radians(30)), math.cos(math.radians(30)), 0.0])
    q = photo_quality(CAM, T_C_W, np.array([4.0, 0.0, 0.0]), u, length=2.0)
    assert q.gsd_mm_px == pytest.approx(4.5, rel=1e-9)


def test_framing_and_gsd_distances_by_hand():
    """2 mm/px with f = 1000 px: 2 m. A horizontal 2 m string with 0.25 m sheds fills 70 % of the
    1280 px width at (2.25 / 2) / tan(0.7 * atan(640 / 1000)) m; a vertical one 70 % of the
    960 px height at (2.25 / 2) / tan(0.7 * atan(480 / 1000))."""
    assert gsd_distance(CAM) == pytest.approx(2.0)
    h = framing_distance(CAM, 2.0, np.array([0.0, 1.0, 0.0]))
    v = framing_distance(CAM, 2.0, np.array([0.0, 0.0, 1.0]))
    assert h == pytest.approx(1.125 / math.tan(FILL_FRACTION * math.atan(0.64)), rel=1e-9)
    assert v == pytest.approx(1.125 / math.tan(FILL_FRACTION * math.atan(0.48)), rel=1e-9)
    # Photographed from there, the string is whole and spans under FILL_FRACTION of the frame
    # (the fraction is of the half field-of-view angle; the sheds' diameter is counted along the
    # axis too, which a square-on view does not need: 2 x 1000 / (h - 0.125) px).
    q = photo_quality(CAM, T_C_W, np.array([h, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), length=2.0,
                      diameter=0.25)
    assert q.whole_in_frame and q.span_share == pytest.approx(2000 / (h - 0.125) / 1280, rel=1e-9)
    assert q.span_share < FILL_FRACTION


def test_bad_arguments_are_named():
    c, u = np.array([4.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    for kw, name in (({"length": 0.0}, "length"), ({"length": 2.0, "diameter": -1.0}, "diameter"),
                     ({"length": 2.0, "exposure": float("nan")}, "exposure"),
                     ({"length": 2.0, "speed": -1.0}, "speed")):
        with pytest.raises(ValueError, match=name):
            photo_quality(CAM, T_C_W, c, u, **kw)
    with pytest.raises(ValueError, match="T_c_w"):
        photo_quality(CAM, np.eye(3), c, u, length=2.0)
    with pytest.raises(ValueError, match="axis"):
        photo_quality(CAM, T_C_W, c, np.zeros(3), length=2.0)
    with pytest.raises(ValueError, match="max_gsd_mm"):
        gsd_distance(CAM, 0.0)
