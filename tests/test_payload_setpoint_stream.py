"""A payload shot never stalls the offboard setpoint stream: while the flight loop waits in
``LiveSensors.photo`` for a shot of the simulated payload, the MAVLink client's own thread keeps
streaming to the simulated PX4 (four times faster than the wall, so its offboard-loss timeout is
a quarter second of wall time). Reference: the stream's gaps as PX4 counts them
(mavlink/setpoint_gaps.py) and the autopilot's mode."""

from __future__ import annotations

import time
from dataclasses import replace

import pytest
from helpers.payload_rig import QUICK, Rig
from helpers.simulated_px4 import TIME_SCALE, connect_new_simulator, take_off_into_offboard

from insulator_rs.drivers.live_sensors import LiveSensors
from insulator_rs.flight.gimbal import stabilised_T_b_c
from insulator_rs.mavlink.setpoint_gaps import OFFBOARD_LOSS_TIMEOUT_S

pytestmark = pytest.mark.slow  # it flies (the simulated PX4)


def test_the_setpoint_stream_runs_on_while_the_loop_waits_for_a_shot() -> None:
    client = connect_new_simulator(time_scale=TIME_SCALE)
    try:
        take_off_into_offboard(client, 3.0)
        client.send_setpoint(client.state().position)
        client.advance(0.5)
        # a capture latency of 0.5 s: the shot outlasts PX4's offboard-loss timeout (1 s of vehicle
        # time, a quarter second of wall time here) whatever the machine's load
        with Rig(dynamics=replace(QUICK, capture_latency_s=0.5)) as r:
            sensors = LiveSensors(None, None, payload=r.adapter, inspection=r.inspection,
                                  pose=lambda: client.state().T_w_b)
            T_b_c = stabilised_T_b_c(client.state().T_w_b, r.inspection.T_b_c, -0.2)
            t0 = time.monotonic()
            frame = sensors.photo(client.state().time, T_b_c, r.inspection.at_focal(400.0))
            waited = time.monotonic() - t0
        assert frame is not None
        # the loop waited longer than PX4 tolerates a silent stream: a stall would have shown
        assert waited * TIME_SCALE > OFFBOARD_LOSS_TIMEOUT_S
        client.advance(0.3)
        record = client.setpoint_gaps.record()
        assert record["past_offboard_loss"] == 0 and record["max_gap_s"] < 0.5 * OFFBOARD_LOSS_TIMEOUT_S, record
        assert client.state().mode == "OFFBOARD"
    finally:
        client.close()
