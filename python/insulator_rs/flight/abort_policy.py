"""When the mission must abort, checked every control tick: the operator asked, the flight-time
limit, the battery reserve (:class:`~insulator_rs.flight.energy_budget.EnergyBudget`), the
camera silent for SENSOR_LOST_TIMEOUT s, the LiDAR silent or the detector failing
(:meth:`~insulator_rs.perception.runner.PerceptionRunner.lost`), or a vehicle fault (unhealthy,
out of OFFBOARD) that does not clear within HOLD_TIMEOUT s of holding. A vehicle failsafe, a
refused command or a leg no safe trajectory can be planned for abort the mission where they happen.
"""

from __future__ import annotations

from insulator_rs.exceptions import VehicleError
from insulator_rs.flight.energy_budget import EnergyBudget
from insulator_rs.flight.pilot import Pilot
from insulator_rs.mission.state_machine import State
from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.ports.vehicle import FlightMode, VehicleState

#: the abort reason's head when a person aborted (Ctrl-C, SIGTERM, the ground station's command):
#: summary.json's status reads "aborted: operator: <how>", as the other aborts name their cause first
OPERATOR = "operator"
SENSOR_LOST_TIMEOUT = 10.0  # s of flight without a new camera frame: the sensor is lost, abort
HOLD_TIMEOUT = 10.0  # s in HOLD before the mission aborts


def operator_reason(how: str) -> str:
    """The abort reason of the operator's abort, ``how`` it was asked (``"Ctrl-C"``,
    ``"ground station"``)."""
    return f"{OPERATOR}: {how}"


class AbortPolicy:
    """The abort rules of one flight; ``max_flight_time``: s of flight before the mission aborts."""

    def __init__(self, pilot: Pilot, runner: PerceptionRunner, energy: EnergyBudget, *,
                 max_flight_time: float) -> None:
        self.pilot = pilot
        self.sm = pilot.sm
        self.runner = runner
        self.energy = energy
        self.max_flight_time = max_flight_time
        self.requested: str | None = None  # the operator's (request), taken at the next check
        self._frames_seen = (0, 0.0)  # camera frames so far, and when that count last grew

    def request(self, reason: str) -> None:
        """The operator aborts the mission (from another thread too)."""
        self.requested = reason

    def started(self, time: float) -> None:
        """The mission started at vehicle ``time``: the camera's silence is counted from there."""
        self._frames_seen = (self.runner.counts.frames, time)

    def due(self, st: VehicleState, t: float) -> str | None:
        """Why the mission must abort now (``st``: the vehicle after this tick, ``t`` s of flight),
        if it must."""
        if self.requested is not None:
            return self.requested
        if t > self.max_flight_time:
            return f"flight time limit of {self.max_flight_time:.0f} s"
        reason = self.energy.check(st, t, self.sm.plan, self.sm.deferred)
        if reason is not None:
            return reason
        frames, since = self._frames_seen
        if self.runner.counts.frames != frames or self.sm.state == State.FINISH:
            self._frames_seen = (self.runner.counts.frames, st.time)
        elif st.time - since > SENSOR_LOST_TIMEOUT:
            return f"sensor lost: no camera frame for {SENSOR_LOST_TIMEOUT:.0f} s"
        if self.sm.state != State.FINISH:  # on the way home perception is over
            return self.runner.lost(st.time, SENSOR_LOST_TIMEOUT)  # the LiDAR silent, the detector failing
        return None

    def hold(self) -> None:
        """HOLD (a vehicle fault): keep position; resume when the vehicle is healthy in offboard
        again, else abort after HOLD_TIMEOUT s."""
        pilot = self.pilot
        st = pilot.vehicle.state()
        here, yaw, t0 = st.position.copy(), st.yaw, st.time
        while self.sm.state == State.HOLD:
            st = pilot.tick(here, None, yaw)
            if self.sm.state != State.HOLD:
                break  # a failsafe aborted the mission
            if st.healthy and st.mode != FlightMode.OFFBOARD.value:
                try:
                    pilot.vehicle.start_offboard()
                except VehicleError as exc:  # the autopilot refused: keep holding
                    pilot.say(f"[{pilot.now():7.1f} s] offboard refused: {exc}")
            if st.healthy and st.mode == FlightMode.OFFBOARD.value:
                self.sm.resume(st.time)
            elif st.time - t0 > HOLD_TIMEOUT:
                pilot.abort(f"fault did not clear within {HOLD_TIMEOUT:.0f} s", st.time)
