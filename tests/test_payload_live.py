"""The live path photographs through the MAVLink payload: the rig's ``[inspection_camera] payload``
fields, and ``LiveSensors.photo`` as one shot of the simulated payload over UDP. Reference: the
camera pose the flight composes (settled T_w_b @ the frame's T_b_c) against the payload's true
camera pose at the capture (the airframe's true pose through the gimbal's true angles; 1e-5 in
rotation, the body's travel during the shot in position)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from helpers.payload_rig import SPEED, TARGET, Rig
from helpers.rig_files import write_zoom_rig

from insulator_rs.drivers.live_sensors import LiveSensors
from insulator_rs.exceptions import ConfigError
from insulator_rs.flight.gimbal import aim_at, stabilised_T_b_c
from insulator_rs.inspection_camera import GimbalRoute, PayloadLink
from insulator_rs.ports.payload import PayloadFault
from insulator_rs.rig import load_rig
from insulator_rs.sim.payload import PayloadFaults


def test_a_rig_names_its_payload(tmp_path):
    rig = load_rig(write_zoom_rig(tmp_path, 'payload = "udpin:0.0.0.0:14560"\npayload_gimbal = "device"\n'
                                            "payload_system = 7\n"))
    assert rig.inspection is not None
    assert rig.inspection.payload == PayloadLink("udpin:0.0.0.0:14560", GimbalRoute.DEVICE, 7)
    plain = load_rig(write_zoom_rig(tmp_path, 'payload = "udpout:192.168.144.25:14550"\n'))
    assert plain.inspection.payload == PayloadLink("udpout:192.168.144.25:14550", GimbalRoute.MANAGER, None)
    assert load_rig(write_zoom_rig(tmp_path, "")).inspection.payload is None


@pytest.mark.parametrize(("table", "field"), [
    ("payload = 14560\n", "inspection_camera.payload"),
    ('payload = "udpin:0.0.0.0:14560"\npayload_gimbal = "camera"\n', "inspection_camera.payload_gimbal"),
    ('payload = "udpin:0.0.0.0:14560"\npayload_system = 0\n', "inspection_camera.payload_system"),
    ("payload_gimbal = \"device\"\n", "inspection_camera.payload_gimbal"),
])
def test_bad_payload_fields_are_named(tmp_path, table, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.") + ":"):
        load_rig(write_zoom_rig(tmp_path, table))


def live(r: Rig) -> LiveSensors:
    return LiveSensors(None, None, payload=r.adapter, inspection=r.inspection, pose=lambda: r.pose(r.clock()))


def test_live_sensors_photograph_through_the_payload_at_the_asked_aim_and_zoom() -> None:
    with Rig() as r:
        sensors = live(r)
        T_w_b = r.pose(r.clock())
        pitch, yaw, T_b_c = aim_at(T_w_b, r.inspection.T_b_c, TARGET, r.inspection.gimbal)
        zoom = r.inspection.at_focal(450.0)
        frame = sensors.photo(r.clock(), T_b_c, camera=zoom)
        assert frame is not None
        assert (frame.camera.fx, frame.camera.fy, frame.camera.cx) == pytest.approx((zoom.fx, zoom.fy, zoom.cx))
        assert (r.sim.pitch, r.sim.yaw) == pytest.approx((pitch, yaw), abs=math.radians(1.0))
        # what the flight composes: the pose it settled at, times the frame's T_b_c
        T_w_c = T_w_b @ frame.T_b_c
        T_true = r.pose(frame.time)
        true_T_w_c = T_true @ stabilised_T_b_c(T_true, r.inspection.T_b_c, r.sim.pitch, r.sim.yaw)
        assert np.allclose(T_w_c[:3, :3], true_T_w_c[:3, :3], atol=1e-5)
        travel = np.linalg.norm(SPEED) * (frame.time - r.clock() + 1.0)
        assert np.linalg.norm(T_w_c[:3, 3] - true_T_w_c[:3, 3]) <= travel
        assert sensors.health()["payload_photos"] == 1 and len(sensors.shots) == 1


def test_a_payload_shot_that_fails_gives_no_photo_and_keeps_its_faults() -> None:
    with Rig(PayloadFaults(refuse_zoom=True)) as r:
        sensors = live(r)
        T_w_b = r.pose(r.clock())
        frame = sensors.photo(r.clock(), stabilised_T_b_c(T_w_b, r.inspection.T_b_c, 0.0), r.inspection.at_focal(400.0))
        assert frame is None
        assert sensors.shots[0].faults == [PayloadFault.ZOOM_REFUSED] * 2
        assert sensors.health()["payload_zoom_refused"] == 2


def test_the_flight_loop_waits_for_a_shot_no_longer_than_its_bound() -> None:
    with Rig(PayloadFaults(capture_silent=True)) as r:
        sensors = LiveSensors(None, None, payload=r.adapter, inspection=r.inspection,
                              pose=lambda: r.pose(r.clock()), shot_wait_s=0.2)
        t0 = time.monotonic()
        frame = sensors.photo(r.clock(), stabilised_T_b_c(r.pose(r.clock()), r.inspection.T_b_c, 0.0))
        assert frame is None and time.monotonic() - t0 < 0.5
        assert sensors.shots_late == 1


def test_live_sensors_need_the_inspection_camera_and_the_pose_with_a_payload() -> None:
    with Rig() as r:
        with pytest.raises(ValueError, match="payload"):
            LiveSensors(None, None, payload=r.adapter)


def test_the_composition_root_opens_the_payload_the_rig_names(tmp_path):
    from insulator_rs.app.live_options import open_payload
    from insulator_rs.exceptions import SensorError
    from insulator_rs.mavlink.payload import MavlinkPayload

    assert open_payload(load_rig(write_zoom_rig(tmp_path, "")), time.monotonic) is None
    rig = load_rig(write_zoom_rig(tmp_path, 'payload = "udpout:127.0.0.1:9"\npayload_gimbal = "device"\n'))
    payload = open_payload(rig, time.monotonic)
    try:
        assert isinstance(payload, MavlinkPayload) and payload.gimbal_route == GimbalRoute.DEVICE
    finally:
        assert payload is not None
        payload.close()
    bad = load_rig(write_zoom_rig(tmp_path, 'payload = "serial-port-nine"\n'))
    with pytest.raises(SensorError, match=r"\[inspection_camera\] payload 'serial-port-nine'"):
        open_payload(bad, time.monotonic)


def test_the_preflight_gate_flies_a_payload_only_when_it_answers() -> None:
    from insulator_rs.flight.preflight import Outcome, check_sensors
    from insulator_rs.ports.sensors import StreamStatus

    class Streams:
        def __init__(self, payload: StreamStatus) -> None:
            self.payload = payload

        def streams(self, now: float) -> list[StreamStatus]:
            return [StreamStatus("camera", 10, now), StreamStatus("lidar", 10, now), self.payload]

    with Rig() as r:
        sensors = live(r)
        payload_stream = sensors.streams(r.clock())[0]
        assert payload_stream.name == "payload" and payload_stream.error is None
        assert check_sensors(Streams(payload_stream), r.clock()).outcome is Outcome.PASSED
        r.sim.vanish()
        time.sleep(r.adapter.settings.lost_after_s + 0.1)
        gone = sensors.streams(r.clock())[0]
        result = check_sensors(Streams(gone), r.clock())
        assert result.outcome is Outcome.FAILED and "payload: no HEARTBEAT" in result.reason
