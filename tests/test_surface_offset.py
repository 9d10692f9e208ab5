"""From the visible surface to the axis (perception/surface_offset.py).

Reference: the true axis of a cylinder built here, its visible half sampled as a LiDAR at range
samples it (evenly across the line of sight), the fitted line taken through the returns' centroid
along the true direction (where a line fit through them lies)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from insulator_rs.perception.photo_quality import STRING_DIAMETER
from insulator_rs.perception.surface_offset import surface_to_axis


def _visible_half(axis_point, axis, sensor, radius, *, length=1.5, n=400, noise=0.0, seed=0):
    """Returns on the half of a cylinder facing ``sensor``, evenly spread across the sight line."""
    rng = np.random.default_rng(seed)
    u = axis / np.linalg.norm(axis)
    sight = axis_point - sensor
    depth = sight - (sight @ u) * u
    depth /= np.linalg.norm(depth)
    lateral = np.cross(u, depth)
    x = rng.uniform(-radius, radius, n)
    t = rng.uniform(-length / 2, length / 2, n)
    z = -np.sqrt(radius**2 - x**2)  # the near side: toward the sensor
    pts = axis_point + np.outer(t, u) + np.outer(x, lateral) + np.outer(z, depth)
    return pts + np.outer(rng.normal(0.0, noise, n), depth), depth  # range noise: along the sight line


@pytest.mark.parametrize("axis", [np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.2, 0.05]), np.array([0.3, -1.0, 0.6])])
@pytest.mark.parametrize("radius", [0.06, 0.11])
def test_the_offset_reaches_the_axis(axis, radius):
    truth = np.array([3.0, -2.0, 9.0])
    sensor = np.array([-5.0, 4.0, 8.0])
    pts, depth = _visible_half(truth, axis, sensor, radius)
    fitted = pts.mean(axis=0)  # the line through the returns, on the near surface
    assert np.linalg.norm(fitted - truth) > 0.5 * radius  # what the correction is for
    corrected = fitted + surface_to_axis(pts, fitted, axis, sensor)
    u = axis / np.linalg.norm(axis)
    off = corrected - truth
    off -= (off @ u) * u  # along the axis the centre is the line fit's business, not this one's
    assert np.linalg.norm(off) < 0.1 * radius


def test_a_mid360s_range_noise_leaves_it_within_a_centimetre():
    truth = np.array([0.0, 0.0, 10.0])
    pts, _ = _visible_half(truth, np.array([0.0, 0.0, 1.0]), np.array([8.0, 0.0, 9.0]), 0.11, noise=0.02)
    fitted = pts.mean(axis=0)
    corrected = fitted + surface_to_axis(pts, fitted, np.array([0.0, 0.0, 1.0]), np.array([8.0, 0.0, 9.0]))
    assert np.linalg.norm((corrected - truth)[:2]) < 0.01


def test_the_offset_points_away_from_the_sensor_and_is_capped():
    """A flat strip 0.38 m wide facing the sensor would read as a 0.19 m radius: capped at the
    widest string's radius."""
    rng = np.random.default_rng(1)
    sensor = np.array([8.0, 0.0, 10.0])
    pts = np.column_stack([np.zeros(300), rng.uniform(-0.19, 0.19, 300), rng.uniform(9.25, 10.75, 300)])
    off = surface_to_axis(pts, pts.mean(axis=0), np.array([0.0, 0.0, 1.0]), sensor)
    assert off[0] < 0 and abs(off[1]) < 1e-3 and abs(off[2]) < 1e-9  # behind the returns, seen from the sensor
    assert math.isclose(np.linalg.norm(off), STRING_DIAMETER / 2)


def test_seen_end_on_or_from_too_few_points_nothing_is_offset():
    truth = np.array([0.0, 0.0, 10.0])
    pts, _ = _visible_half(truth, np.array([1.0, 0.0, 0.0]), np.array([-8.0, 0.0, 11.0]), 0.1)
    # the sensor almost on the axis's line: no near surface across it
    assert not np.any(surface_to_axis(pts, pts.mean(axis=0), np.array([1.0, 0.0, 0.0]), np.array([-8.0, 0.0, 10.05])))
    few = pts[:5]
    assert not np.any(surface_to_axis(few, few.mean(axis=0), np.array([1.0, 0.0, 0.0]), np.array([0.0, 8.0, 10.0])))
