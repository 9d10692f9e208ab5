"""PX4 v1.16 SITL as the gimbal manager of the simulated payload (MNT_MODE_IN = 4, MNT_MODE_OUT = 2).

The payload sits on PX4's gimbal MAVLink link (udp 13030 + N, PX4's ``-m gimbal`` instance) as a
real one sits on a serial port of the flight controller; the adapter talks to PX4's onboard link
(14540 + N) as the companion does. The companion's aim (MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, then
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW) must come out of PX4 as GIMBAL_DEVICE_SET_ATTITUDE to our
gimbal device, which turns there (its true attitude against the aim, 1 degree); the camera's
commands, CAMERA_IMAGE_CAPTURED and the MAVLink FTP download go through PX4's forwarding.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from helpers.payload_rig import ORIGIN, inspection_camera, scene
from helpers.px4_sitl import Px4Sitl
from helpers.sitl_suite import FOLDER, SITL_MARKS

from insulator_rs.mavlink.payload import GimbalRoute, MavlinkPayload, PayloadSettings
from insulator_rs.poses import pose_from_yaw
from insulator_rs.ports.payload import ShotRequest
from insulator_rs.sim.payload import SimulatedPayload, scene_photo_renderer

pytestmark = SITL_MARKS
GIMBAL_LINK_LOCAL = 13030  # PX4's gimbal link (+ instance): where it listens
GIMBAL_LINK_REMOTE = 13280  # and where it sends (+ instance): the payload's port


def test_px4_gimbal_manager_forwards_the_companions_aim_to_our_gimbal_device(monkeypatch: pytest.MonkeyPatch,
                                                                            tmp_path: object) -> None:
    assert FOLDER is not None
    monkeypatch.setenv("PX4_PARAM_MNT_MODE_IN", "4")  # MAVLink gimbal protocol v2 in
    monkeypatch.setenv("PX4_PARAM_MNT_MODE_OUT", "2")  # MAVLink gimbal protocol v2 out
    with Px4Sitl(FOLDER, first_instance=7) as px4:
        system = px4.instance + 1  # PX4 SITL instance N is system N + 1; the payload is part of it
        inspection = inspection_camera()
        t0 = time.monotonic()
        payload = SimulatedPayload(inspection, pose=lambda t: pose_from_yaw(np.array([0.0, 0.0, 5.0]), 0.0),
                                   clock=lambda: time.monotonic() - t0, render=scene_photo_renderer(scene()), origin=ORIGIN,
                                   system_id=system, port=GIMBAL_LINK_REMOTE + px4.instance,
                                   peer=("127.0.0.1", GIMBAL_LINK_LOCAL + px4.instance)).start()
        adapter = MavlinkPayload(px4.connection, inspection, gimbal_route=GimbalRoute.MANAGER, target_system=system,
                                 settings=PayloadSettings(command_timeout_s=1.0, slew_timeout_s=10.0))
        try:
            deadline = time.monotonic() + 30.0
            while not adapter.alive() and time.monotonic() < deadline:  # PX4 forwards the heartbeats
                time.sleep(0.1)
            assert adapter.alive(), px4.log()[-2000:]
            pitch, yaw = math.radians(-30), math.radians(20)
            result = adapter.submit(ShotRequest(pitch, yaw, 500.0)).result(timeout=120)
            log = px4.log()
            assert payload.counts["set_attitude"] > 0, (result.attempts, log[-2000:])
            assert (payload.pitch, payload.yaw) == pytest.approx((pitch, yaw), abs=math.radians(1.0))
            assert "Configured primary gimbal control" in log
            assert result.photo is not None, result.attempts
            assert result.photo.image.shape == (120, 160, 3)
            axis = result.photo.R_w_c[:, 2]  # the optical axis in W, from CAMERA_IMAGE_CAPTURED.q
            assert math.asin(axis[2]) == pytest.approx(pitch, abs=math.radians(1.0))
            assert math.atan2(axis[1], axis[0]) == pytest.approx(yaw, abs=math.radians(1.0))  # the body faces east
        finally:
            adapter.close()
            payload.close()


@pytest.mark.realtime  # the sensor head renders in real time: beside other flights it starves
def test_a_live_small_scene_flight_photographs_through_the_payload(px4, tmp_path) -> None:
    """The live path against PX4 SITL with the payload: the sensor head (PX4's pose) plays the
    inspection camera as a MAVLink gimbal-and-zoom payload (``--payload-port``), the rig names it
    (``[inspection_camera] payload``), and ``insulator-rs inspect`` with the live drivers takes every
    inspection photo through it: aimed, zoomed, captured and fetched by MAVLink FTP. Reference: the
    photos' size (the payload's, not the detection camera's), the payload's own counters in
    summary.json, the scene's ground truth and PX4's log (no failsafe)."""
    from helpers.flights import small_scene
    from helpers.live_sitl import LIVE_SCALE, PAYLOAD_SCALE, fly_live

    from insulator_rs.rig import simulator_rig

    scene, mission = small_scene(tmp_path)
    flight = fly_live(px4, tmp_path, scene, mission, payload=True)
    s = flight.summary
    print(f"live SITL flight with the payload: {flight.line()}; {flight.head_output.strip()}")
    assert not flight.failsafe
    assert flight.returncode == 0 and flight.status == "finished", (flight.status, flight.stdout[-2000:],
                                                                    flight.stderr[-2000:])
    health = s["sensors_health"]
    assert health["payload_photos"] >= 1 and health["payload_photos"] == len(s["photos"]), health
    wide = simulator_rig().inspection_camera().camera
    size = (round(wide.width * PAYLOAD_SCALE), round(wide.height * PAYLOAD_SCALE))
    assert size != (round(simulator_rig().camera.width * LIVE_SCALE), round(simulator_rig().camera.height * LIVE_SCALE))
    import cv2

    for photo in s["photos"]:
        image = cv2.imread(str(tmp_path / "report" / photo["file"]))
        assert image is not None and (image.shape[1], image.shape[0]) == size, photo["file"]
