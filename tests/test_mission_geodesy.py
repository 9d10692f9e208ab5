"""Geodesy: GPS <-> W round trips and the line frame."""

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs.geodesy import GeoPoint, enu_to_gps, gps_to_enu, line_frame

ORIGIN = GeoPoint(50.08, 14.42, 300.0)


@settings(max_examples=60, deadline=None)
@given(e=st.floats(-3000, 3000), n=st.floats(-3000, 3000), u=st.floats(-100, 500),
       lat=st.floats(-80, 80), lon=st.floats(-179, 179))
def test_enu_gps_round_trip(e, n, u, lat, lon):
    """W -> GPS -> W returns the point within 1 mm (pymap3d both ways)."""
    origin = GeoPoint(lat, lon, 100.0)
    back = gps_to_enu(enu_to_gps(np.array([e, n, u]), origin), origin)
    np.testing.assert_allclose(back, [e, n, u], atol=1e-3)


def test_enu_distance_matches_ecef_distance():
    """Reference: straight-line ECEF distance (pymap3d.geodetic2ecef), tolerance 1 mm; ENU is a
    rotation of the ECEF difference, so the norms must agree."""
    p = GeoPoint(50.081, 14.4235, 320.0)
    enu = gps_to_enu(p, ORIGIN)
    a = np.array(pymap3d.geodetic2ecef(ORIGIN.lat, ORIGIN.lon, ORIGIN.alt))
    b = np.array(pymap3d.geodetic2ecef(p.lat, p.lon, p.alt))
    assert abs(np.linalg.norm(enu) - np.linalg.norm(b - a)) < 1e-3
    assert enu[0] > 0 and enu[1] > 0 and enu[2] > 0  # east, north, up of the origin


def test_one_arcminute_north_is_about_a_nautical_mile():
    enu = gps_to_enu(GeoPoint(ORIGIN.lat + 1 / 60, ORIGIN.lon, ORIGIN.alt), ORIGIN)
    assert abs(enu[1] - 1853.0) < 10 and abs(enu[0]) < 1e-6


def test_line_frame_from_two_neighbours_and_sides():
    nb = np.array([[-100.0, -100.0, 0.0], [100.0, 100.0, 2.0]])
    lf = line_frame(nb)
    np.testing.assert_allclose(lf.along, [np.sqrt(0.5), np.sqrt(0.5), 0.0])
    np.testing.assert_allclose(np.cross(lf.along, [0, 0, 1.0]), lf.lateral)
    assert lf.side(np.array([5.0, -5.0, 10.0])) == 1
    assert lf.side(np.array([-5.0, 5.0, 10.0])) == -1
    pts = np.random.default_rng(0).normal(size=(20, 3)) * 30
    np.testing.assert_allclose(lf.to_world(lf.to_line(pts)), pts, atol=1e-12)


def test_line_frame_one_neighbour_points_at_it():
    lf = line_frame(np.array([[0.0, -200.0, 0.0]]))
    np.testing.assert_allclose(lf.along, [0, -1, 0], atol=1e-12)


@pytest.mark.parametrize("nb, match", [
    (np.zeros((0, 3)), "1 or 2"),
    (np.array([[0.1, 0.2, 0.0]]), r"neighbours_enu\[0\]"),
    (np.array([[50.0, 0, 0], [50.0, 0, 0]]), "coincide"),
    (np.array([[np.nan, 0, 0]]), "finite"),
])
def test_line_frame_rejects_bad_neighbours(nb, match):
    with pytest.raises(ValueError, match=match):
        line_frame(nb)
