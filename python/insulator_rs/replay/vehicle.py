"""The replay's :class:`~insulator_rs.ports.vehicle.Vehicle`: a passive vehicle that plays the
recorded poses, as PX4's replay feeds recorded topics to the same modules.

``advance`` moves the clock to the recording's next datum (a pose, a scan or a frame: the
recording sets the pace, so every datum gets its own tick and no pose is skipped); ``state``
is the latest recorded pose at that time. A replay flies nothing: every command is refused.
"""

from __future__ import annotations

import numpy as np

from insulator_rs.exceptions import CommandRejected
from insulator_rs.poses import quaternion_from_rotation, yaw_of
from insulator_rs.ports.sensors import PoseStamped
from insulator_rs.ports.vehicle import VehicleState
from insulator_rs.replay.player import RecordingPlayer

REPLAY_MODE = "REPLAY"


class ReplayVehicle:
    """Plays a recording's poses (see the module docstring)."""

    def __init__(self, player: RecordingPlayer) -> None:
        self.player = player
        self._previous: PoseStamped | None = None  # the pose before the latest (for the velocity)

    @property
    def ended(self) -> bool:
        return self.player.ended

    def pose(self) -> PoseStamped | None:
        """The latest recorded pose (full attitude, as recorded), None before the first."""
        return self.player.pose

    def state(self) -> VehicleState:
        pose = self.player.pose
        now = self.player.time if self.player.time is not None else 0.0
        if pose is None:
            return VehicleState(now, np.zeros(3), np.zeros(3), 0.0, armed=False, mode=REPLAY_MODE, landed=True)
        R = pose.T_w_b[:3, :3]
        velocity = np.zeros(3)
        prev = self._previous
        if prev is not None and pose.time > prev.time:  # the recorded positions' difference
            velocity = (pose.T_w_b[:3, 3] - prev.T_w_b[:3, 3]) / (pose.time - prev.time)
        return VehicleState(now, pose.T_w_b[:3, 3].copy(), velocity, yaw_of(R),
                            armed=True, mode=REPLAY_MODE, landed=False, attitude=quaternion_from_rotation(R))

    def advance(self, dt: float) -> VehicleState:
        """To the recording's next datum (``dt`` is not used: the recording sets the pace)."""
        self.step()
        return self.state()

    def step(self) -> None:
        """:meth:`advance` without building the state: the replay's own loop reads the recorded
        pose itself, at every datum (a state a datum was a tenth of a tower A replay's loop)."""
        before = self.player.pose
        if self.player.next() is not None and self.player.pose is not before:
            self._previous = before

    def _refuse(self, command: str) -> None:
        raise CommandRejected(command, "a replay plays a recorded flight and flies nothing", temporary=False)

    def arm(self) -> None:
        self._refuse("arm")

    def start_offboard(self) -> None:
        self._refuse("offboard")

    def takeoff(self, altitude: float) -> None:
        self._refuse("takeoff")

    def send_setpoint(self, position: np.ndarray, velocity: np.ndarray | None = None,
                      yaw: float | None = None) -> None:
        self._refuse("setpoint")

    def land(self) -> None:
        self._refuse("land")

    def hold(self) -> None:
        self._refuse("hold")

    def close(self) -> None:
        pass
