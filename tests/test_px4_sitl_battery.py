"""PX4 SIH's battery read through the MAVLink adapter and fitted by the battery reserve's estimator.

PX4 v1.16.0 SITL (``../shared/px4_sitl``) simulates its pack in the ``battery_simulator`` module:
while armed the charge falls linearly over SIM_BAT_DRAIN s (default 60) and stops at
SIM_BAT_MIN_PCT (default 50 %); PX4's battery library turns the simulated voltage back into a
charge and BATTERY_STATUS / SYS_STATUS carry it as whole percents. The test sets both
parameters over MAVLink (PARAM_SET on PX4's GCS link, answered by PARAM_VALUE: pymavlink's
``param_set_send`` directly, not the parameter module on another branch), flies a short hover
and shuttle through :class:`~insulator_rs.mavlink.client.MavlinkVehicle`, and feeds every state
to :class:`~insulator_rs.flight.reserve.BatteryReserve`.

Reference: SIM_BAT_DRAIN itself. SIH's drain is by time only, so the fitted per-second rate
must be 1 / SIM_BAT_DRAIN within FIT_TOLERANCE (PX4's voltage filter and the 1 % steps), and the
per-metre rate must explain at most a small share of the drop.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from helpers.sitl_suite import SITL_MARKS, SPEED

pytestmark = SITL_MARKS
GCS_PORT = 18570  # PX4 SITL's GCS link listens on 18570 + instance
DRAIN_S = 300.0  # SIM_BAT_DRAIN: the whole pack in 5 minutes, 20 % in the minute flown here
MIN_PCT = 5.0  # SIM_BAT_MIN_PCT: well below what the flight reaches (PX4's 50 % would stop the drain)
FLIGHT_S = 70.0  # s of vehicle time in the air
FIT_TOLERANCE = 0.15  # relative, on the per-second rate


def _set_parameters(port: int, values: dict[str, float], timeout: float = 30.0) -> dict[str, float]:
    """PARAM_SET each value on PX4's GCS link; PX4's PARAM_VALUE answers, by name."""
    from insulator_rs.mavlink.wire import mavlink2 as M
    from insulator_rs.mavlink.wire import mavutil

    link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        link.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
        heartbeat = link.recv_match(type="HEARTBEAT", blocking=True, timeout=timeout)
        assert heartbeat is not None, f"no HEARTBEAT on the GCS link {port}"
        target = heartbeat.get_srcSystem()
        answers: dict[str, float] = {}
        for name, value in values.items():
            deadline = time.monotonic() + 10.0
            while name not in answers and time.monotonic() < deadline:
                link.mav.param_set_send(target, 1, name.encode(), float(value), M.MAV_PARAM_TYPE_REAL32)
                until = time.monotonic() + 1.0
                while time.monotonic() < until:
                    msg = link.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
                    if msg is not None and msg.param_id == name:
                        answers[name] = float(msg.param_value)
                        break
        return answers
    finally:
        link.close()


def test_px4_sih_battery_is_read_and_fitted(px4) -> None:
    from insulator_rs.flight.reserve import BatteryReserve
    from insulator_rs.mavlink.client import connect_vehicle

    answers = _set_parameters(GCS_PORT + px4.instance, {"SIM_BAT_DRAIN": DRAIN_S, "SIM_BAT_MIN_PCT": MIN_PCT})
    assert answers == {"SIM_BAT_DRAIN": pytest.approx(DRAIN_S), "SIM_BAT_MIN_PCT": pytest.approx(MIN_PCT)}
    vehicle = connect_vehicle(px4.connection, time_scale=SPEED)
    reserve = BatteryReserve(0.25)
    charges = []
    try:
        st = vehicle.state()
        deadline = time.monotonic() + 10.0
        while st.battery_fraction is None and time.monotonic() < deadline:
            st = vehicle.advance(0.1)
        assert st.battery_fraction is not None, "no battery charge from PX4 (BATTERY_STATUS / SYS_STATUS)"
        home = st.position.copy()
        for _ in range(20):  # the setpoint stream PX4 wants before OFFBOARD
            vehicle.send_setpoint(home, None, st.yaw)
            st = vehicle.advance(0.05)
        vehicle.arm()
        vehicle.start_offboard()
        t0 = st.time
        # climb to 5 m, then shuttle 8 m back and forth along x (distance beside the time)
        while st.time - t0 < FLIGHT_S:
            t = st.time - t0
            x = 0.0 if t < 10.0 else 4.0 * (1.0 - math.cos(2 * math.pi * (t - 10.0) / 20.0))
            vehicle.send_setpoint(home + np.array([x, 0.0, 5.0]), None, st.yaw)
            st = vehicle.advance(0.05)
            reserve.observe(st)
            if st.battery_fraction is not None:
                charges.append((st.time - t0, st.battery_fraction))
        vehicle.land()
        deadline = time.monotonic() + 60.0
        while not st.landed and time.monotonic() < deadline:
            st = vehicle.advance(0.1)
            reserve.observe(st)
    finally:
        vehicle.close()
    fit = reserve.fit()
    record = reserve.record()
    first, last = charges[0][1], charges[-1][1]
    print(f"PX4 SIH battery: {first:.2f} -> {last:.2f} in {FLIGHT_S:g} s, {reserve.d_air:.0f} m; fit {record['fit']}")
    assert record["known"] and reserve.readings > 0
    assert first - last > 0.1, f"PX4's charge should have fallen about {FLIGHT_S / DRAIN_S:.0%}: {first} -> {last}"
    assert fit is not None
    assert fit.per_s == pytest.approx(1.0 / DRAIN_S, rel=FIT_TOLERANCE), record["fit"]
    # SIH drains by time only: the distance term explains little of the drop
    assert fit.per_m * reserve.d_air < 0.25 * (first - last), record["fit"]
