"""The MAVLink payload adapter (mavlink/payload.py) against the simulated payload (sim/payload.py)
over real UDP: aim, zoom, capture, the file fetched by MAVLink FTP, the photo's pose from the
capture message; and each fault as a named outcome per attempt.

References: the ground truth of a one-box scene projected with ``cv2.projectPoints`` through the
photo's own pose (position from its WGS-84 fix through pymap3d, attitude from its quaternion) and
intrinsics, against the red blob the simulator's ray caster drew (2 px); the airframe's true
pose at the capture instant (1 cm), not at the request.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Iterator

import cv2
import numpy as np
import pytest

from helpers.payload_rig import FAST, ORIGIN, QUICK, TARGET, Rig, inspection_camera
from insulator_rs.flight.gimbal import stabilised_T_b_c
from insulator_rs.geodesy import GeoPoint, gps_to_enu
from insulator_rs.mavlink.payload import CAMERA_COMPONENT, MavlinkPayload, PayloadSettings, ftp_path
from insulator_rs.mavlink.wire import mavlink2 as M
from insulator_rs.ports.payload import Payload, PayloadFault, ShotRequest
from insulator_rs.sim.payload import PayloadFaults


@pytest.fixture
def rig() -> Iterator[Rig]:
    with Rig() as r:
        yield r


def test_a_shot_is_aimed_zoomed_captured_fetched_and_posed_from_the_capture_message(rig: Rig) -> None:
    pitch, yaw = rig.aim()
    t_request = rig.clock()
    result = rig.adapter.submit(ShotRequest(pitch, yaw, 500.0)).result(timeout=5.0)
    assert result.faults == [] and result.photo is not None, result.attempts
    photo = result.photo
    # intrinsics: the rig's per-zoom table at the asked focal length (between the two calibrations)
    expected = rig.inspection.at_focal(500.0)
    assert (photo.camera.fx, photo.camera.cx) == pytest.approx((expected.fx, expected.cx))
    assert photo.image.shape == (120, 160, 3) and photo.file_url.startswith("mftp://")
    # the pose is the capture's: the airframe's true pose at the capture instant, not at the request
    assert photo.time > t_request + QUICK.capture_latency_s
    T_w_b = rig.pose(photo.time)
    true_T_w_c = T_w_b @ stabilised_T_b_c(T_w_b, rig.inspection.T_b_c, rig.sim.pitch, rig.sim.yaw)
    position = gps_to_enu(GeoPoint(*photo.wgs84), ORIGIN)
    assert np.linalg.norm(position - true_T_w_c[:3, 3]) < 0.01
    assert np.linalg.norm(position - (rig.pose(t_request) @ np.r_[rig.inspection.T_b_c[:3, 3], 1])[:3]) > 0.05
    assert np.allclose(photo.R_w_c, true_T_w_c[:3, :3], atol=1e-5)
    # the box, projected by OpenCV through the photo's own pose and intrinsics, is where it was drawn
    R_c_w = photo.R_w_c.T
    uv, _ = cv2.projectPoints(TARGET.reshape(1, 3), cv2.Rodrigues(R_c_w)[0], -R_c_w @ position,
                              photo.camera.camera_matrix(), np.zeros(5))
    b, g, red = (photo.image[:, :, i].astype(int) for i in range(3))
    ys, xs = np.nonzero((red > 80) & (red > 2 * g + 20) & (red > 2 * b + 20))  # the red box
    assert len(xs) > 50
    assert np.hypot(xs.mean() - uv[0, 0, 0], ys.mean() - uv[0, 0, 1]) < 2.0
    assert rig.adapter.health()["photos"] == 1


def test_a_lost_capture_message_is_asked_for_again_by_its_index() -> None:
    with Rig(PayloadFaults(lost_capture_rate=1.0)) as r:
        result = r.adapter.submit(ShotRequest(0.0, 0.0, 300.0)).result(timeout=5.0)
        assert result.photo is not None and len(result.attempts) == 1
        assert r.sim.counts["captured_lost"] == 1


@pytest.mark.parametrize(("faults", "request_", "fault"), [
    (PayloadFaults(capture_silent=True), ShotRequest(0.0, 0.0, 300.0), PayloadFault.NO_CAPTURE_ANSWER),
    (PayloadFaults(refuse_zoom=True), ShotRequest(0.0, 0.0, 300.0), PayloadFault.ZOOM_REFUSED),
    (PayloadFaults(pitch_stop=math.radians(-20)), ShotRequest(math.radians(-40), 0.0, 300.0),
     PayloadFault.GIMBAL_AT_LIMIT),
], ids=["capture_never_answers", "zoom_refused", "gimbal_stopped_short"])
def test_each_fault_is_named_per_attempt_and_retried(faults: PayloadFaults, request_: ShotRequest,
                                                    fault: PayloadFault) -> None:
    with Rig(faults) as r:
        result = r.adapter.submit(request_).result(timeout=5.0)
        assert result.photo is None
        expected_attempts = 1 if fault is PayloadFault.GIMBAL_AT_LIMIT else FAST.attempts
        assert result.faults == [fault] * expected_attempts, result.attempts
        assert r.adapter.health()[fault.value] == expected_attempts


def test_an_aim_past_the_advertised_range_is_refused_at_once(rig: Rig) -> None:
    t0 = time.monotonic()
    result = rig.adapter.submit(ShotRequest(math.radians(60), 0.0, 300.0)).result(timeout=5.0)
    assert result.faults == [PayloadFault.GIMBAL_AT_LIMIT]
    assert "past the gimbal's range" in result.attempts[0].detail
    assert time.monotonic() - t0 < FAST.slew_timeout_s
    assert rig.sim.counts["set_attitude"] == 0


def test_a_download_cut_halfway_fails_that_attempt_and_the_retry_fetches_it() -> None:
    with Rig(PayloadFaults(downloads_cut=1)) as r:
        result = r.adapter.submit(ShotRequest(0.0, 0.0, 300.0)).result(timeout=5.0)
        assert result.faults == [PayloadFault.DOWNLOAD_FAILED], result.attempts
        assert result.photo is not None and result.photo.image_index == 1
        assert "bytes" in result.attempts[0].detail


def test_a_payload_gone_mid_flight_is_named_and_the_caller_never_waits() -> None:
    with Rig() as r:
        r.sim.vanish()
        time.sleep(FAST.lost_after_s + 0.1)
        t0 = time.monotonic()
        future = r.adapter.submit(ShotRequest(0.0, 0.0, 300.0))
        assert time.monotonic() - t0 < 0.05  # the control loop's tick is not taken by the payload
        result = future.result(timeout=5.0)
        assert result.photo is None and result.faults == [PayloadFault.PAYLOAD_LOST] * FAST.attempts


def test_zoom_by_range_where_the_rig_has_no_pixel_pitch() -> None:
    with Rig(pixel_pitch_um=None) as r:
        result = r.adapter.submit(ShotRequest(0.0, 0.0, 650.0)).result(timeout=5.0)
        assert result.photo is not None, result.attempts
        assert r.sim.focal_px == pytest.approx(650.0, rel=0.011)


def test_an_image_named_by_an_http_url_is_fetched_over_http() -> None:
    with Rig(http=True) as r:
        result = r.adapter.submit(ShotRequest(0.0, 0.0, 300.0)).result(timeout=5.0)
        assert result.photo is not None, result.attempts
        assert result.photo.file_url.startswith("http://")
        assert r.sim.counts["ftp_requests"] == 0


def test_the_adapter_is_a_payload_port(rig: Rig) -> None:
    assert isinstance(rig.adapter, Payload)


@pytest.mark.parametrize(("url", "expected"), [
    ("mftp:///DCIM/IMG_0001.jpg", ("/DCIM/IMG_0001.jpg", None)),
    ("mftp://;comp=100/DCIM/a.jpg", ("/DCIM/a.jpg", 100)),
    ("mftp://[;comp=154]/x.jpg", ("/x.jpg", 154)),
    ("/DCIM/b.jpg", ("/DCIM/b.jpg", None)),
])
def test_ftp_urls(url: str, expected: tuple[str, int | None]) -> None:
    assert ftp_path(url) == expected


def test_settings_refuse_bad_values() -> None:
    with pytest.raises(ValueError, match="attempts"):
        PayloadSettings(attempts=0)
    with pytest.raises(ValueError, match="ftp_idle_s"):
        PayloadSettings(ftp_retry_s=1.0, ftp_idle_s=0.5)
    with pytest.raises(ValueError, match="gimbal_route"):
        MavlinkPayload("udpout:127.0.0.1:9", inspection_camera(), gimbal_route="sideways")


def test_the_cameras_clock_is_mapped_to_the_vehicles() -> None:
    """A camera that counts from its own boot: its stamps are mapped by the least offset seen."""
    with Rig() as r:
        r.adapter.close()
        r.sim.peer = None  # the payload answers whoever speaks to it next
        offset = 1000.0  # the vehicle clock runs this far ahead of the camera's
        adapter = MavlinkPayload(r.sim.url, r.inspection, gimbal_route="device", settings=FAST,
                                 vehicle_clock=lambda: r.clock() + offset)
        try:
            deadline = time.monotonic() + 2.0
            while not adapter.alive() and time.monotonic() < deadline:
                time.sleep(0.02)
            t_request = r.clock() + offset
            result = adapter.submit(ShotRequest(0.0, 0.0, 300.0)).result(timeout=5.0)
            assert result.photo is not None, result.attempts
            captured = r.sim.images[-1].message[0] / 1000.0  # the camera's stamp of the capture
            assert result.photo.time == pytest.approx(captured + offset, abs=0.05)
            assert result.photo.time > t_request
        finally:
            adapter.close()


def test_a_retransmitted_capture_command_is_not_a_second_shot() -> None:
    with Rig() as r:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        me = M.MAVLink(None, srcSystem=1, srcComponent=M.MAV_COMP_ID_ONBOARD_COMPUTER)
        try:
            for confirmation, sequence in ((0, 1), (1, 1), (0, 2)):
                sock.sendto(me.command_long_encode(1, CAMERA_COMPONENT, M.MAV_CMD_IMAGE_START_CAPTURE, confirmation,
                                                   0, 0, 1, sequence, 0, 0, 0).pack(me), r.sim.address)
            deadline = time.monotonic() + 2.0
            while len(r.sim.images) < 2 and time.monotonic() < deadline:
                time.sleep(0.02)
            time.sleep(0.1)
            assert len(r.sim.images) == 2  # sequence 1 once, sequence 2 once
        finally:
            sock.close()


def test_an_http_download_cut_halfway_fails_that_attempt_and_the_retry_fetches_it() -> None:
    with Rig(PayloadFaults(downloads_cut=1), http=True) as r:
        result = r.adapter.submit(ShotRequest(0.0, 0.0, 300.0)).result(timeout=5.0)
        assert result.faults == [PayloadFault.DOWNLOAD_FAILED], result.attempts
        assert "IncompleteRead" in result.attempts[0].detail
        assert result.photo is not None and result.photo.file_url.startswith("http://")
