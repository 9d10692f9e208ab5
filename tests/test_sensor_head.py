"""The SITL sensor head's pose feed (``insulator_rs.sim.sensor_head``): PX4's pose in W between
and past its telemetry samples. Reference: straight-line motion at constant velocity and yaw
rate, whose pose at any instant is known in closed form; the attitude conversion against the
MAVLink boundary's own (``insulator_rs.mavlink.frames``), which the flight client uses."""

from __future__ import annotations

import math
import threading
from collections import deque

import numpy as np
import pytest

from insulator_rs.exceptions import InsulatorError
from insulator_rs.mavlink.frames import attitude_ned_frd_to_enu_flu
from insulator_rs.sim.sensor_head import LatencyQueue, Px4PoseFeed, _body_rotation


def feed(samples: int = 100) -> Px4PoseFeed:
    """A feed holding ``samples`` 50 Hz samples of x = 1 m/s * t, yaw_enu = 0.1 rad/s * t."""
    f = Px4PoseFeed.__new__(Px4PoseFeed)  # no MAVLink link: only the pose arithmetic under test
    f._lock, f.local_origin_w = threading.Lock(), np.array([1.0, 2.0, 3.0])
    ts = [k * 0.02 for k in range(samples)]
    f._pos = deque([(t, np.array([t, 0.0, 5.0]), np.array([1.0, 0.0, 0.0])) for t in ts], maxlen=500)
    f._att = deque([(t, 0.1 * t, 0.0, 0.0, 0.1) for t in ts], maxlen=500)
    return f


@pytest.mark.parametrize("t", [-0.5, 0.0, 0.511, 1.0, 1.98, 2.5])
def test_pose_between_and_past_samples(t: float) -> None:
    T = feed().pose(t)
    assert np.allclose(T[:3, 3], [1.0 + t, 2.0, 8.0], atol=1e-12)
    assert math.isclose(math.atan2(T[1, 0], T[0, 0]), 0.1 * t, abs_tol=1e-12)
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3)) and np.allclose(T[2, :3], [0, 0, 1])


def test_no_pose_before_telemetry() -> None:
    f = feed()
    f._pos.clear()
    with pytest.raises(InsulatorError, match="no pose"):
        f.pose(0.0)


@pytest.mark.parametrize("roll,pitch,yaw_enu", [(0.0, 0.0, 0.3), (0.1, -0.05, 2.0), (-0.2, 0.15, -1.2)])
def test_full_attitude_is_the_mavlink_boundary_conversion(roll: float, pitch: float, yaw_enu: float) -> None:
    R = _body_rotation(yaw_enu, roll, pitch)
    assert np.allclose(R, attitude_ned_frd_to_enu_flu(roll, pitch, math.pi / 2 - yaw_enu), atol=1e-12)
    if roll == pitch == 0.0:  # level: the heading alone
        assert math.isclose(math.atan2(R[1, 0], R[0, 0]), yaw_enu, abs_tol=1e-12) and math.isclose(R[2, 2], 1.0)


def test_the_latency_queue_releases_each_chunk_at_its_arrival_plus_the_latency() -> None:
    """Reference: arrival + latency, by hand. Chunks rendered together leave one by one at their
    own times; none early, the oldest first."""
    q = LatencyQueue(0.05)
    q.add([(1.000, [b"a"]), (1.008, [b"b"]), (1.016, [b"c"])])
    assert q.due(1.049) == [] and math.isclose(q.next_due() or 0.0, 1.05)
    assert [c for _, c in q.due(1.050)] == [[b"a"]]
    assert [c for _, c in q.due(1.070)] == [[b"b"], [b"c"]] and q.next_due() is None and len(q) == 0
    zero = LatencyQueue(0.0)  # the default: as soon as rendered
    zero.add([(2.0, [b"d"])])
    assert [c for _, c in zero.due(2.0)] == [[b"d"]]


@pytest.mark.parametrize("bad", [-0.01, 0.6, float("nan")])
def test_a_bad_latency_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="latency_s"):
        LatencyQueue(bad)


@pytest.mark.parametrize("z_estimate", [-0.3, -0.05, 0.0, 0.1])
def test_a_landed_airframe_is_rendered_on_its_gear_not_inside_the_ground(z_estimate: float) -> None:
    """PX4's estimate of an airframe standing on the ground wanders 0.3 m below it to 0.05 m above
    (PX4 SITL v1.16); the head renders from the airframe on its gear. Reference: the scene mesh's
    own inside test (``Mesh.enclosing_instance``) at the rig's LiDAR and camera positions."""
    from insulator_rs.rig import simulator_rig
    from insulator_rs.sim.sensors import LANDING_GEAR_HEIGHT, resting_on
    from insulator_rs.sim.towers import GROUND_Z, load_tower

    mesh = load_tower("tower_b").mesh
    estimate = np.eye(4)
    estimate[:3, 3] = [20.0, -15.0, GROUND_Z + z_estimate]  # clear of the tower, over the ground
    rig = simulator_rig()
    T = resting_on(lambda t: estimate, GROUND_Z)(0.0)
    assert T[2, 3] == pytest.approx(GROUND_Z + LANDING_GEAR_HEIGHT) and np.allclose(T[:2, 3], estimate[:2, 3])
    for T_b_s in (rig.T_b_l, rig.T_b_c):
        assert mesh.enclosing_instance((T @ T_b_s)[:3, 3]) is None
    if z_estimate <= 0.0:  # the raw estimate puts the camera inside the ground: what the head sent nothing for
        assert mesh.enclosing_instance((estimate @ rig.T_b_c)[:3, 3]) is not None


def test_an_airborne_pose_is_rendered_as_estimated() -> None:
    from insulator_rs.sim.sensors import resting_on

    estimate = np.eye(4)
    estimate[:3, 3] = [1.0, 2.0, 7.5]
    assert np.array_equal(resting_on(lambda t: estimate, 0.0)(3.0), estimate)
