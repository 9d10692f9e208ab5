"""Our setpoint stream's gaps (mavlink/setpoint_gaps.py): what tells the report that PX4 failed
safe for a moment (PX4 v1.16 clears its offboard-loss fallback when setpoints resume, often
between two of its 1 Hz heartbeats, so the client's mode monitor may never see it).

References: gaps made here at known times (the unit tests), and a stream stalled by holding the
interpreter for a known time against the simulated PX4 (the whole process stands still, as it did
in session 17's SITL flight)."""

from __future__ import annotations

import pytest
from helpers.interpreter_stall import hold_the_interpreter  # a whole-process stall, as a long GIL hold makes
from helpers.simulated_px4 import TIME_SCALE, connect_new_simulator, take_off_into_offboard

from insulator_rs.exceptions import VehicleFailsafe
from insulator_rs.mavlink.setpoint_gaps import LISTED_GAP_S, OFFBOARD_LOSS_TIMEOUT_S, SetpointGaps
from insulator_rs.planning.px4_failsafes import OFFBOARD_LOSS_TIMEOUT


def test_the_loss_timeout_is_the_one_the_mission_sets_on_px4():
    assert OFFBOARD_LOSS_TIMEOUT_S == OFFBOARD_LOSS_TIMEOUT


def test_gaps_are_listed_and_the_ones_past_px4s_timeout_counted():
    gaps = SetpointGaps()
    for t in (0.0, 0.05, 0.10, 0.75, 0.80, 2.0, 2.05):  # gaps 0.65 s and 1.2 s
        gaps.sent_at(t)
    r = gaps.record()
    assert r["sent"] == 7 and r["gaps"] == 2 and r["past_offboard_loss"] == 1
    assert r["max_gap_s"] == pytest.approx(1.2) and r["longest_s"] == [pytest.approx(1.2), pytest.approx(0.65)]
    assert r["listed_from_s"] == LISTED_GAP_S and r["offboard_loss_timeout_s"] == 1.0


def test_the_clients_own_pauses_are_not_gaps():
    gaps = SetpointGaps()
    gaps.sent_at(0.0)
    gaps.paused()  # take-off, landing, leaving OFFBOARD
    gaps.sent_at(30.0)
    gaps.sent_at(30.05)
    r = gaps.record()
    assert r["gaps"] == 0 and r["max_gap_s"] == pytest.approx(0.05)


def test_gaps_are_in_vehicle_seconds():
    gaps = SetpointGaps(time_scale=4.0)  # a simulated PX4 four times faster than the wall
    gaps.sent_at(0.0)
    gaps.sent_at(0.3)
    assert gaps.record()["max_gap_s"] == pytest.approx(1.2) and gaps.record()["past_offboard_loss"] == 1


def test_a_stalled_stream_against_the_simulated_px4_is_counted_past_the_loss_timeout():
    client = connect_new_simulator(time_scale=TIME_SCALE)
    try:
        take_off_into_offboard(client, 3.0)
        client.send_setpoint(client.state().position)
        client.advance(0.5)
        before = client.setpoint_gaps.record()
        assert before["sent"] > 0
        hold_the_interpreter(1.5 * OFFBOARD_LOSS_TIMEOUT_S / TIME_SCALE)  # 1.5 s of vehicle time
        try:
            client.advance(0.5)
        except VehicleFailsafe:  # the simulated PX4 failed safe on the gap, as PX4 does
            pass
        r = client.setpoint_gaps.record()
        assert r["past_offboard_loss"] >= 1 and r["max_gap_s"] >= 1.4 * OFFBOARD_LOSS_TIMEOUT_S, r
    finally:
        client.close()
