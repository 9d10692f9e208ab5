"""The simulated PX4 (``insulator_rs.sim.px4``) for the MAVLink tests: real MAVLink 2 over UDP
on 127.0.0.1. Each client gets a freshly started simulator, found again with ``sim_of``. The
vehicle clock runs ``TIME_SCALE`` times faster than the wall clock (PX4's timeouts scale with
it); ``DT`` is the vehicle-time step the tests advance by."""

from __future__ import annotations

from typing import Any

from insulator_rs.mavlink.client import MavlinkVehicle
from insulator_rs.sim.px4 import SimulatedPx4, start_simulated_px4

TIME_SCALE = 4.0
DT = 0.05


_SIMULATORS: dict[int, SimulatedPx4] = {}


def connect_new_simulator(**options: Any) -> MavlinkVehicle:
    """A client of a freshly started simulated PX4 (``start_simulated_px4``); ``sim_of`` finds it."""
    sim, client = start_simulated_px4(**options)
    _SIMULATORS[id(client)] = sim
    return client


def sim_of(client: MavlinkVehicle) -> SimulatedPx4:
    return _SIMULATORS[id(client)]


def wait_until(client: MavlinkVehicle, predicate, vehicle_seconds: float) -> None:
    """Advance the vehicle clock until predicate(state) holds (fail after vehicle_seconds)."""
    end = client.state().time + vehicle_seconds
    while client.state().time < end:
        if predicate(client.state()):
            return
        client.advance(DT)
    raise AssertionError(f"condition not reached in {vehicle_seconds} s of vehicle time: {client.state()}")


def take_off_into_offboard(client: MavlinkVehicle, altitude: float = 3.0) -> None:
    client.arm()
    client.takeoff(altitude)
    wait_until(client, lambda s: s.mode == "HOLD" and abs(s.position[2] - altitude) < 0.1, 15.0)
    client.send_setpoint(client.state().position)
    client.advance(0.3)
    client.start_offboard()


def started_simulators(monkeypatch):
    """The simulated PX4s this test's runs start (``start_simulated_px4`` returns the one it
    starts to the composition root; the test records them on ``SimulatedPx4.start``)."""
    from insulator_rs.sim.px4 import SimulatedPx4

    sims = []
    original = SimulatedPx4.start

    def start(self):
        sims.append(self)
        return original(self)

    monkeypatch.setattr(SimulatedPx4, "start", start)
    return sims
