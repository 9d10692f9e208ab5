"""The ground-truth photo check (evaluation/photo_coverage.py): a string covered by photos at
>= 60 % of the long side and <= 2 mm/px, through each photo's own pose and intrinsics."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

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
