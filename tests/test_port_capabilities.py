"""The ports' optional capabilities (ports/capabilities.py): found by ``isinstance`` on the adapter,
and through a decorator (recording, fault injection) exactly when the adapter it wraps has them.

Reference: what each adapter is known to offer: the MAVLink client (parameters, navigation,
TIMESYNC, the setpoint stream's gaps) against the in-process simulator (none of them); the
getters the flight reads (parameters, navigation, the TIMESYNC and setpoint-stream records).
"""

from __future__ import annotations

import numpy as np

from insulator_rs.flight.record import setpoint_stream_record, timesync_record
from insulator_rs.ports.capabilities import (HasParameters, MapsClock, NavigationStatus, ReportsNavigation,
                                             ReportsSetpointStream)
from insulator_rs.ports.detector import detector_name, detections_dropped
from insulator_rs.ports.vehicle import VehicleDecorator, vehicle_navigation, vehicle_parameters
from insulator_rs.sim.kinematics import KinematicVehicle
from insulator_rs.timesync import TimesyncRecord

CAPABILITIES = (HasParameters, ReportsNavigation, MapsClock, ReportsSetpointStream)


class Store:
    def read(self, name):
        return 1

    def set(self, name, value):
        return value

    def ground_station(self, wait):
        return True


class Gaps:
    def record(self):
        return {"longest_s": 0.07}


class Autopilot(KinematicVehicle):
    """The in-process vehicle with what the MAVLink client adds (its names, its types)."""

    def __init__(self):
        super().__init__()
        self.parameters = Store()
        self.setpoint_gaps = Gaps()

    def navigation(self):
        return NavigationStatus(3, 12, (47.0, 8.0, 500.0), (47.0, 8.0, 500.0))

    def timesync_record(self):
        return TimesyncRecord(source="timesync")


class Recording(VehicleDecorator):
    """A decorator as the recording's: overrides a call, adds nothing."""

    def state(self):
        return self.inner.state()


def test_the_simulator_has_none_and_a_decorator_adds_none():
    for vehicle in (KinematicVehicle(), Recording(KinematicVehicle())):
        assert not any(isinstance(vehicle, c) for c in CAPABILITIES)
        assert vehicle_parameters(vehicle) is None and vehicle_navigation(vehicle) is None
        assert setpoint_stream_record(vehicle) is None
        assert timesync_record(vehicle, object()).source == "none"


def test_a_decorator_offers_what_its_autopilot_has_and_hands_it_on():
    inner = Autopilot()
    for vehicle in (inner, Recording(inner), Recording(Recording(inner))):
        assert all(isinstance(vehicle, c) for c in CAPABILITIES)
        assert vehicle_parameters(vehicle) is inner.parameters
        assert vehicle_navigation(vehicle) == inner.navigation()
        assert setpoint_stream_record(vehicle) == {"longest_s": 0.07}
        assert timesync_record(vehicle, object()).source == "timesync"
    # the port's own calls still go to the inner adapter
    inner.send_setpoint(np.array([0.0, 0.0, 1.0]), None, 0.0)
    assert Recording(inner).advance(0.05).time == inner.state().time


def test_a_decorator_no_longer_passes_anything_else_on():
    vehicle = Recording(Autopilot())
    assert not hasattr(vehicle, "home") and vehicle.inner.home is not None


def test_a_detector_says_its_name_and_drops_where_it_has_them():
    def plain(image):
        return np.zeros((0, 5))

    assert detector_name(plain) == "function" and detections_dropped(plain) is None

    class Named:
        name = "yolo11n"

        def __call__(self, image):
            return np.zeros((0, 5))

    assert detector_name(Named()) == "yolo11n" and detections_dropped(Named()) is None
