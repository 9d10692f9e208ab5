"""The payload's faults in the fault matrix (issue 46 item 4): the flight photographs through the
simulated MAVLink payload over real UDP, against our simulated PX4, and each payload fault begins
at the inspection moment.

Each cell, measured as the matrix measures (``insulator_rs.evaluation.fault_matrix``): the
clearance from the scene's TRUE mesh to the airframe's TRUE trajectory up to the landing, against
the mission's margin; landed; summary.json names, for each insulator without a photo, the fault
each attempt met (the payload's ``PayloadFault`` name); the attempts per shot within the
adapter's bound; and the offboard setpoint stream's longest gap, as PX4 counts it
(mavlink/setpoint_gaps.py), below PX4's offboard-loss timeout, with no gap past it, while the
loop waited for every failing shot. The quick tests check the pieces the cells compose.
"""

from __future__ import annotations

import json
import math
from typing import Any

import pytest

from helpers.payload_rig import Rig
from insulator_rs.drivers.live_sensors import LiveSensors, shot_failure
from insulator_rs.evaluation import fault_matrix as FM
from insulator_rs.evaluation import payload_faults as PF
from insulator_rs.flight.gimbal import stabilised_T_b_c
from insulator_rs.flight.photos import InspectionPhotos
from insulator_rs.mavlink.payload import FINAL_FAULTS, PayloadSettings
from insulator_rs.mavlink.setpoint_gaps import OFFBOARD_LOSS_TIMEOUT_S
from insulator_rs.ports.capabilities import ExplainsMissingPhoto
from insulator_rs.ports.payload import PayloadAttempt, PayloadFault, ShotResult
from insulator_rs.ports.sensors import SensorsDecorator
from insulator_rs.rig import scaled_camera, simulator_rig
from insulator_rs.sim.payload import PayloadFaults

# s after arming of the inspection moment, read by FM.moments_from off the clean flight's state log
INSPECTION_S = 10.1


def test_the_wall_clocked_bounds_and_motions_scale_with_the_simulators_speed_up() -> None:
    base, fast = PayloadSettings(), PF.scaled_settings(4.0)
    assert fast.attempts == base.attempts and fast.command_tries == base.command_tries
    assert fast.capture_timeout_s == base.capture_timeout_s / 4 and fast.lost_after_s == base.lost_after_s / 4
    assert fast.aim_tolerance_rad == base.aim_tolerance_rad and fast.zoom_tolerance_pct == base.zoom_tolerance_pct
    d = PF.scaled_dynamics(4.0)
    assert d.slew_rate == 4 * PF.PayloadDynamics().slew_rate
    assert d.capture_latency_s == PF.PayloadDynamics().capture_latency_s  # on the vehicle clock already


def test_the_scaled_inspection_camera_is_the_rigs_at_the_photo_scale() -> None:
    inspection = simulator_rig().inspection_camera()
    small = PF.scaled_inspection(inspection, 0.2)
    reference = scaled_camera(inspection.camera, 0.2)
    assert (small.camera.width, small.camera.height) == (reference.width, reference.height)
    assert small.focal_px[0] == pytest.approx(0.5 * (reference.fx + reference.fy), rel=1e-9)
    long_end = scaled_camera(inspection.at_focal(inspection.focal_px[1]), 0.2)
    assert small.focal_px[1] == pytest.approx(0.5 * (long_end.fx + long_end.fy), rel=1e-3)


def test_a_failed_shot_is_said_by_each_attempts_fault_and_the_photos_keep_it_per_insulator() -> None:
    result = ShotResult(None, (PayloadAttempt(1, PayloadFault.DOWNLOAD_FAILED, "cut"),
                               PayloadAttempt(2, PayloadFault.DOWNLOAD_FAILED, "cut")))
    why = shot_failure(result)
    assert why == "payload: download_failed (attempt 1), download_failed (attempt 2)"
    photos = InspectionPhotos(None, 1.0)  # type: ignore[arg-type]  (no photo is saved)
    photos.missing(3, why)
    photos.missing(3, why)
    without = photos.check_summary([3, 4])["insulators_without_fit_photo"]
    assert without == [{"insulator_id": 3, "photos": 0, "reasons": {why: 2}, "errors": []},
                       {"insulator_id": 4, "photos": 0, "reasons": {"no photo taken": 1}, "errors": []}]
    summary = {"photo_checks": {"insulators_without_fit_photo": without}}
    assert PF.photos_missing(summary) == f"insulator 3: {why} x2; insulator 4: no photo taken x1"


class _Plain:
    """Sensors that photograph nothing (the detection frames and scans are not asked here)."""

    def photo(self, now: float, T_b_c: Any, camera: Any = None) -> None:
        return None

    def health(self) -> dict[str, object]:
        return {"plain": 1}

    def close(self) -> None:
        pass


def test_a_fault_injected_mid_flight_fails_the_next_shot_with_its_name_through_the_decorators() -> None:
    """The payload healthy, then the capture fault injected: the first photo comes, the second
    gives none, and the reason passes through a second decorator (the recording's place)."""
    with Rig() as r:
        through = LiveSensors(None, None, payload=r.adapter, inspection=r.inspection,
                              pose=lambda: r.pose(r.clock()))
        sensors = SensorsDecorator(PF.PayloadSensors(_Plain(), through, 1.0))  # type: ignore[arg-type]
        assert isinstance(sensors, ExplainsMissingPhoto)
        pitch, yaw = r.aim()
        T_b_c = stabilised_T_b_c(r.pose(r.clock()), r.inspection.T_b_c, pitch)
        assert sensors.photo(r.clock(), T_b_c, r.inspection.at_focal(400.0)) is not None
        assert sensors.photo_failure() is None
        r.sim.inject(PayloadFaults(capture_silent=True))
        assert sensors.photo(r.clock(), T_b_c, r.inspection.at_focal(400.0)) is None
        assert sensors.photo_failure() == "payload: " + ", ".join(
            f"no_capture_answer (attempt {n})" for n in range(1, r.adapter.settings.attempts + 1))
        assert sensors.health()["plain"] == 1 and sensors.health()["payload_no_capture_answer"] == 2


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> FM.Setup:
    from insulator_rs.mission.config import load_mission
    from insulator_rs.sim.towers import load_tower

    folder = tmp_path_factory.mktemp("payload_faults")
    scene, mission = FM.small_scene(folder, FM.PACKAGE / "scenes", FM.PACKAGE / "missions")
    tower = load_tower(str(scene))
    return FM.Setup(scene, mission, tower, FM.Structure(tower.mesh), load_mission(mission).inspection.safety_margin)


@pytest.mark.slow
@pytest.mark.parametrize("fault", list(PF.PAYLOAD_FAULTS))
def test_a_payload_fault_cell_is_safe_bounded_reported_per_insulator_and_never_stalls_the_stream(
        setup: FM.Setup, tmp_path: Any, fault: str) -> None:
    cell = FM.fly_cell(setup, fault, "inspection", INSPECTION_S, tmp_path / "cell")
    assert cell.clearance_m >= setup.margin, f"{cell.clearance_m} m from the {cell.nearest}"
    assert cell.ended.startswith("landed"), cell.ended
    summary = json.loads((tmp_path / "cell" / "report" / "summary.json").read_text(encoding="utf-8"))
    name = PF.PAYLOAD_FAULTS[fault].value
    # every insulator found is reported without a photo, for the fault its attempts met
    without = summary["photo_checks"]["insulators_without_fit_photo"]
    found = [i["id"] for i in summary["insulators"]]
    assert found and sorted(w["insulator_id"] for w in without) == sorted(found), cell.photos_missing
    assert all(any(name in reason for reason in w["reasons"]) for w in without), cell.photos_missing
    assert cell.report_names_fault
    # each shot tried a bounded number of times: the adapter's attempts, one for a fault it does not retry
    health = summary["sensors_health"]
    shots, attempts = int(health["payload_shots"]), int(health["payload_attempts"])
    per_shot = 1 if PF.PAYLOAD_FAULTS[fault] in FINAL_FAULTS else PF.scaled_settings(FM.TIME_SCALE).attempts
    assert shots > 0 and attempts <= shots * per_shot, health
    assert int(health["payload_photos"]) == 0 and int(health["payload_shots_late"]) == 0, health
    # the stream ran on while the loop waited for every failing shot
    stream = summary["setpoint_stream"]
    assert cell.max_setpoint_gap_s is not None and math.isfinite(cell.max_setpoint_gap_s)
    assert stream["past_offboard_loss"] == 0 and cell.max_setpoint_gap_s < OFFBOARD_LOSS_TIMEOUT_S, stream
