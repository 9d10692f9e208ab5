"""Everything the planners derive from a mission file, built once: the line frame, the safety
volumes, the take-off point and the exploration path (all in W)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from insulator_rs.mission.config import Mission
from insulator_rs.planning.exploration import PathWaypoint, exploration_path
from insulator_rs.geodesy import LineFrame
from insulator_rs.planning.safety import SafetyVolumes, safety_volumes


@dataclass(frozen=True)
class MissionGeometry:
    """The planning geometry of one mission (W, metres)."""

    mission: Mission
    line: LineFrame
    volumes: SafetyVolumes
    takeoff: np.ndarray
    path: list[PathWaypoint]

    @classmethod
    def from_mission(cls, mission: Mission) -> MissionGeometry:
        line = mission.line()
        p = mission.inspection
        volumes = safety_volumes(line, max_width=mission.max_width, max_height=mission.max_height,
                                 margin=p.safety_margin)
        takeoff = mission.takeoff_enu()
        # the passes' spacing follows what the airframe's sensors see (the simulated one's by default)
        rig = mission.sensor_rig()
        try:
            path = exploration_path(line, volumes, takeoff=takeoff, max_width=mission.max_width,
                                    max_height=mission.max_height, standoff=p.standoff,
                                    pass_spacing=p.pass_spacing,
                                    crossing_clearance=p.crossing_clearance, view=rig.vertical_view())
        except ValueError as exc:
            raise ValueError(f"{mission.source}: {exc}") from exc
        return cls(mission, line, volumes, takeoff, path)

    def path_points(self) -> np.ndarray:
        """The exploration path's waypoints (M, 3) in W."""
        return np.array([w.position for w in self.path])
