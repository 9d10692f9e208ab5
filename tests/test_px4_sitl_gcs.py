"""What PX4 v1.16.0 SITL forwards between the companion and the ground station, measured.

PX4's SITL start-up (``etc/init.d-posix/px4-rc.mavlink``) runs its GCS link on UDP 18570+N
and the offboard/API link on 14580+N (to the companion on 14540+N), both with forwarding
(``-f``). Measured here (and mirrored by our simulated PX4's ``gcs_port``, sim/px4_gcs.py):

* companion -> GCS: forwarded unchanged (the companion's system and component ids): the
  HEARTBEATs of its camera (100) and onboard computer (191), STATUSTEXT of either with its
  severity, CAMERA_INFORMATION, CAMERA_IMAGE_CAPTURED, a COMMAND_LONG addressed to the GCS;
* GCS -> companion: its HEARTBEAT and its COMMAND_LONGs addressed to components 100 and 191;
  one addressed to the autopilot (component 1) PX4 answers itself and does not forward;
* bursts: 10 CAMERA_IMAGE_CAPTURED (~230 bytes each) sent back to back: 2 reached the GCS (twice);
  2 ms apart: 7; 5, 10 and 20 ms apart: all 10. 10 short STATUSTEXTs back to back: all 10.
  So the observer paces its frames (10 ms) and the simulated PX4 models the buffer.

Then the real thing: our MAVLink client connected to PX4 as in a flight, the GCS observer on
the client's own link, and a GCS on PX4's GCS port that receives every STATUSTEXT and
CAMERA_IMAGE_CAPTURED and gets the CAMERA_INFORMATION it asks for.
"""

from __future__ import annotations

import socket
import time
from collections import Counter

import numpy as np
import pytest
from helpers.gcs_listener import GcsListener, M
from helpers.px4_sitl import Px4Sitl
from helpers.sitl_suite import FOLDER, SITL_MARKS

from insulator_rs.mavlink.client import MavlinkVehicle
from insulator_rs.mavlink.gcs import CAMERA_COMPONENT, COMPANION_COMPONENT, MavlinkGcsObserver
from insulator_rs.ports.observer import PhaseChange, PhotoTaken

pytestmark = SITL_MARKS
GCS_PORT = 18570
OFFBOARD_LOCAL = 14580
OFFBOARD_REMOTE = 14540


class _RawPeer:
    """A bare MAVLink peer on UDP (the measurement uses no code of ours)."""

    def __init__(self, bind: tuple[str, int], dest: tuple[str, int], system: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.dest, self.system = dest, system
        self._mavs: dict[int, object] = {}
        self._in = M.MAVLink(None)
        self._in.robust_parsing = True
        self.got: list = []

    def write(self, buf: bytes) -> None:
        self.sock.sendto(buf, self.dest)

    def mav(self, component: int):
        if component not in self._mavs:
            self._mavs[component] = M.MAVLink(self, srcSystem=self.system, srcComponent=component)
        return self._mavs[component]

    def poll(self) -> None:
        while True:
            try:
                data, _ = self.sock.recvfrom(65535)
            except BlockingIOError:
                return
            self.got.extend(m for m in (self._in.parse_buffer(data) or []) if m.get_type() != "BAD_DATA")

    def kinds(self):
        return Counter((m.get_srcSystem(), m.get_srcComponent(), m.get_type()) for m in self.got)


def test_what_px4_forwards_between_companion_and_gcs():
    with Px4Sitl(FOLDER, first_instance=3) as px4:
        i, sysid = px4.instance, px4.instance + 1
        comp = _RawPeer(("127.0.0.1", OFFBOARD_REMOTE + i), ("127.0.0.1", OFFBOARD_LOCAL + i), sysid)
        gcs = _RawPeer(("127.0.0.1", 0), ("127.0.0.1", GCS_PORT + i), 255)
        t0 = time.monotonic()
        sent = asked = False
        next_hb = 0.0
        while time.monotonic() - t0 < 12.0:
            el = time.monotonic() - t0
            if el >= next_hb:
                next_hb += 1.0
                gcs.mav(190).heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
                comp.mav(191).heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                             M.MAV_STATE_ACTIVE)
                comp.mav(100).heartbeat_send(M.MAV_TYPE_CAMERA, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
            if el > 3.0 and not sent:
                sent = True
                comp.mav(191).statustext_send(M.MAV_SEVERITY_NOTICE, b"probe from 191", 0, 0)
                comp.mav(100).statustext_send(M.MAV_SEVERITY_WARNING, b"probe from 100", 0, 0)
                name = list(b"probe".ljust(32, b"\0"))
                comp.mav(100).camera_information_send(1, name, name, 0, 8.0, 6.2, 4.6, 4000, 3000, 0,
                                                      M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE, 0, b"")
                comp.mav(100).camera_image_captured_send(1, 0, 0, 473977420, 85455940, 500000, 12000,
                                                         [1, 0, 0, 0], 0, 1, b"images/probe.jpg")
                comp.mav(191).command_long_send(255, 190, M.MAV_CMD_REQUEST_MESSAGE, 0, 1, 0, 0, 0, 0, 0, 0)
            if el > 5.0 and not asked:
                asked = True
                for target in (CAMERA_COMPONENT, COMPANION_COMPONENT, 1):
                    gcs.mav(190).command_long_send(sysid, target, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                                   M.MAVLINK_MSG_ID_CAMERA_INFORMATION, 0, 0, 0, 0, 0, 0)
            comp.poll()
            gcs.poll()
            time.sleep(0.01)
        comp.poll()
        gcs.poll()
    got = gcs.kinds()
    print("GCS got from the companion:", {k: n for k, n in got.items() if k[1] != 1})
    for kind in ((sysid, 100, "HEARTBEAT"), (sysid, 191, "HEARTBEAT"), (sysid, 100, "STATUSTEXT"),
                 (sysid, 191, "STATUSTEXT"), (sysid, 100, "CAMERA_INFORMATION"),
                 (sysid, 100, "CAMERA_IMAGE_CAPTURED"), (sysid, 191, "COMMAND_LONG")):
        assert got[kind] >= 1, kind
    sev = {m.text: m.severity for m in gcs.got if m.get_type() == "STATUSTEXT"}
    assert sev["probe from 191"] == M.MAV_SEVERITY_NOTICE and sev["probe from 100"] == M.MAV_SEVERITY_WARNING
    cap = next(m for m in gcs.got if m.get_type() == "CAMERA_IMAGE_CAPTURED")
    assert (cap.lat, cap.lon, cap.file_url) == (473977420, 85455940, "images/probe.jpg")
    back = [m.target_component for m in comp.got if m.get_type() == "COMMAND_LONG" and m.get_srcSystem() == 255]
    print("companion got the GCS's commands to components:", back)
    assert sorted(back) == [CAMERA_COMPONENT, COMPANION_COMPONENT]  # not the one to the autopilot
    assert any(m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 255 for m in comp.got)
    # PX4 answered the one to itself
    assert any(m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_REQUEST_MESSAGE for m in gcs.got)


def test_px4_forwards_a_burst_of_large_frames_only_in_part():
    with Px4Sitl(FOLDER, first_instance=3) as px4:
        i, sysid = px4.instance, px4.instance + 1
        comp = _RawPeer(("127.0.0.1", OFFBOARD_REMOTE + i), ("127.0.0.1", OFFBOARD_LOCAL + i), sysid)
        gcs = _RawPeer(("127.0.0.1", 0), ("127.0.0.1", GCS_PORT + i), 255)
        for _ in range(3):
            gcs.mav(190).heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
            comp.mav(191).heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                         M.MAV_STATE_ACTIVE)
            time.sleep(1.0)
            comp.poll()
            gcs.poll()
        got = {}
        for gap in (0.0, 0.01):
            tag = f"gap{gap:g}"
            for k in range(10):
                comp.mav(100).camera_image_captured_send(1, 0, 0, 1, 2, 3, 4, [1, 0, 0, 0], k, 1,
                                                         (f"{tag} " + "x" * 150).encode())
                if gap:
                    time.sleep(gap)
            t = time.monotonic()
            while time.monotonic() - t < 1.0:
                comp.poll()
                gcs.poll()
                time.sleep(0.005)
            got[gap] = sum(1 for m in gcs.got if m.get_type() == "CAMERA_IMAGE_CAPTURED"
                           and m.file_url.startswith(tag + " "))
    print("of 10 large frames, PX4 forwarded:", got)
    assert got[0.0] < 10 and got[0.01] == 10


def test_gcs_on_px4_sitl_gets_statustext_and_every_photo_marker():
    with Px4Sitl(FOLDER, first_instance=3) as px4:
        vehicle = MavlinkVehicle(px4.connection, heartbeat_timeout=30.0)
        try:
            sysid = vehicle.autopilot[0]
            with GcsListener(("127.0.0.1", GCS_PORT + px4.instance)) as gcs:
                assert gcs.wait_for(lambda: gcs.of("HEARTBEAT", 1), 10.0)
                obs = MavlinkGcsObserver.on_vehicle(vehicle)
                obs.phase(PhaseChange(1.0, "idle", "explore", "take-off done"))
                for k in range(5):
                    obs.photo_taken(PhotoTaken(10.0 + k, time.time(), 1 + k // 2, k + 1,
                                               f"images/insulator_{1 + k // 2:02d}_{k % 2 + 1}.jpg",
                                               np.array([1.0, 2.0, 9.0]), (47.397742, 8.545594 + 1e-6 * k, 497.0),
                                               0.5 * k, -0.3))
                obs.aborted(30.0, "test over")
                gcs.command_long((sysid, CAMERA_COMPONENT), M.MAV_CMD_REQUEST_MESSAGE,
                                 M.MAVLINK_MSG_ID_CAMERA_INFORMATION)
                assert gcs.wait_for(lambda: len(gcs.of("CAMERA_IMAGE_CAPTURED")) == 5
                                    and len(gcs.of("CAMERA_INFORMATION")) >= 2
                                    and gcs.of("COMMAND_ACK", CAMERA_COMPONENT), 10.0), \
                    str(sorted((k, n) for k, n in gcs.count().items() if k[1] != 1)) + str(obs.sent)
                time.sleep(1.5)
                obs.close()
        finally:
            vehicle.close()
    caps = gcs.of("CAMERA_IMAGE_CAPTURED", CAMERA_COMPONENT)
    assert [c.image_index for c in caps] == [0, 1, 2, 3, 4]
    assert all(c.get_srcSystem() == sysid for c in caps)
    texts = gcs.statustexts()
    print("STATUSTEXT on the GCS:", texts)
    mine = [(s, t) for c, s, t in texts if c == COMPANION_COMPONENT]
    assert (M.MAV_SEVERITY_INFO, "Inspection: idle -> explore (take-off done)") in mine
    assert (M.MAV_SEVERITY_CRITICAL, "Inspection aborted: test over") in mine
    assert sum(t.startswith("Photo ") for _, t in mine) == 5
    assert len(gcs.of("HEARTBEAT", CAMERA_COMPONENT)) >= 2  # 1 Hz, forwarded


# one worker flies the session's reference flight for all three tests that read it (conftest.py)
@pytest.mark.xdist_group("sitl_reference_flight")
def test_small_scene_flight_against_px4_sitl_shows_every_photo_on_its_gcs(reference_flight):
    """The small-scene inspection flown through PX4 (``inspect --connection ... --sim-sensors``;
    the session's one reference flight, ``sitl_reference_flight``) with a ground station on PX4's
    own GCS port: it gets a STATUSTEXT and a CAMERA_IMAGE_CAPTURED for every photo of the
    report, the mission's phase changes, and the camera's information."""
    s, gcs, rc = reference_flight.summary, reference_flight.gcs, reference_flight.rc
    assert rc == 0 and s["status"] == "finished", s["status"]
    photos = s["photos"]
    assert len(photos) >= 4
    caps = gcs.of("CAMERA_IMAGE_CAPTURED", CAMERA_COMPONENT)
    print(f"{len(photos)} photos; the GCS got {len(caps)} CAMERA_IMAGE_CAPTURED, "
          f"{len(gcs.statustexts())} STATUSTEXT; {gcs.count()[(reference_flight.instance + 1, CAMERA_COMPONENT, 'HEARTBEAT')]} "
          f"camera heartbeats; asked again for images {gcs.images_requested}; the GCS socket dropped "
          f"{gcs.drops_at_close} datagrams")
    # every photo reached the GCS: sent as taken, or sent again when the GCS asked by index (the
    # camera protocol's recovery, as QGroundControl keeps its photo list whole)
    first = {}
    for c in caps:
        first.setdefault(c.image_index, c)
    assert sorted(first) == list(range(len(photos)))
    for c, p in zip((first[i] for i in range(len(photos))), photos):
        assert c.file_url.endswith(p["file"])
        assert abs(c.lat - p["wgs84"]["lat"] * 1e7) <= 1 and abs(c.lon - p["wgs84"]["lon"] * 1e7) <= 1
    texts = [t for comp, _, t in gcs.statustexts() if comp == COMPANION_COMPONENT]
    assert sum(t.startswith("Photo ") for t in texts) == len(photos)
    for tr in s["transitions"]:
        assert any(t.startswith(f"Inspection: {tr['from']} -> {tr['to']}") for t in texts), tr
    assert gcs.cameras_asked and gcs.of("CAMERA_INFORMATION", CAMERA_COMPONENT)
