"""The composition root's one wiring: the adapters chosen behind the flight loop's ports,
decorated and handed to :class:`~insulator_rs.flight.loop.FlightLoop`, which knows none of them.

``insulator-rs inspect`` (:mod:`insulator_rs.app.inspect_command`: simulated, SITL or live
sensors, any vehicle) and the fault matrix (:mod:`insulator_rs.evaluation.fault_matrix`: the
simulator with faults round its ports) both assemble their flights here, so a recording, a
fault or a detector is wired the same way in both. The choice of the adapters stays with the
caller; this module only puts them together:

* :func:`simulated_ports`: the simulator's camera and Mid-360 rendered at a pose source, and
  the detector (the network given, else the simulator's ground-truth stand-in, named as such);
* :func:`assemble_flight`: the recorder (when given) wraps the vehicle and the sensors (the
  flight does not know it is recorded), an outer decorator (a fault) may wrap the recorded
  vehicle, and the loop is built on the result.

It lives with the simulator because the dependency rules let only ``sim/``, ``evaluation/``
and ``app/`` see both the flight and the recorder, and the fault matrix (``evaluation/``) may
not import ``app/``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from insulator_rs.flight.loop import FlightLoop, FlightSettings
from insulator_rs.ports.observer import FlightObserver
from insulator_rs.mission.config import Mission
from insulator_rs.ports.detector import BoxDetector
from insulator_rs.ports.sensors import Sensors
from insulator_rs.ports.vehicle import Vehicle
from insulator_rs.rig import SensorRig
from insulator_rs.sim.ground_truth_detector import GroundTruthDetector
from insulator_rs.sim.mesh import Mesh
from insulator_rs.sim.sensors import DETECT_SCALE, PoseSource, SimulatedSensors

if TYPE_CHECKING:  # recording needs the bags extra: a bare install flies without it
    from insulator_rs.recording.writer import McapRecorder


@dataclass(frozen=True)
class SimulatedPorts:
    """The simulator's ``sensors``, the flight's ``detector`` and the ``photo_camera`` the photos
    are taken with (the inspection camera at the sensors' photo resolution)."""

    sensors: SimulatedSensors
    detector: BoxDetector
    photo_camera: Any


def simulated_ports(mesh: Mesh, pose: PoseSource, rig: SensorRig, *, seed: int, detect_scale: float = DETECT_SCALE,
                    photo_scale: float = 1.0, camera_latency_s: float = 0.0,
                    network: BoxDetector | None = None) -> SimulatedPorts:
    """``rig``'s sensors rendered in ``mesh`` at ``pose()`` (see
    :class:`~insulator_rs.sim.sensors.SimulatedSensors` for the scales and the latency), and
    ``network`` as the detector, or the ground-truth stand-in when None; all seeded from ``seed``."""
    sensors = SimulatedSensors(mesh, pose, rig, detect_scale=detect_scale, photo_scale=photo_scale, seed=seed,
                               camera_latency_s=camera_latency_s)
    detector: BoxDetector = network if network is not None else GroundTruthDetector(sensors, seed=seed)
    return SimulatedPorts(sensors, detector, sensors.photo_model)


@dataclass(frozen=True)
class AssembledFlight:
    """The loop, and the ports as it sees them (decorated: close these, they pass it on)."""

    loop: FlightLoop
    vehicle: Vehicle
    sensors: Sensors


def assemble_flight(mission: Mission, vehicle: Vehicle, sensors: Sensors, detector: BoxDetector, out: Path, *,
                    rig: SensorRig, settings: FlightSettings, photo_camera: Any = None,
                    recorder: McapRecorder | None = None, observer: FlightObserver | None = None,
                    overwrite: bool = False,
                    outer_vehicle: Callable[[Vehicle], Vehicle] | None = None,
                    photo_detector: BoxDetector | None = None) -> AssembledFlight:
    """The flight of ``mission`` on these ports, its report into ``out``: recorded into
    ``recorder`` when given (the pose stream and every frame and scan the flight asks for, with
    ``rig``'s T_b_l), the recorded vehicle wrapped by ``outer_vehicle`` when given (what it adds,
    a fault, stays out of the recording); ``photo_camera``, ``observer``, ``overwrite``,
    ``photo_detector`` (what checks each photo; default ``detector``) and ``settings`` as
    :class:`~insulator_rs.flight.loop.FlightLoop`'s."""
    if recorder is not None:
        from insulator_rs.recording.writer import RecordingSensors, RecordingVehicle

        vehicle = RecordingVehicle(vehicle, recorder)
        sensors = RecordingSensors(sensors, recorder, T_b_l=rig.T_b_l)
    if outer_vehicle is not None:
        vehicle = outer_vehicle(vehicle)
    loop = FlightLoop(mission, vehicle, sensors, detector, out, rig=rig, settings=settings, overwrite=overwrite,
                      photo_camera=photo_camera, observer=observer, photo_detector=photo_detector)
    return AssembledFlight(loop, vehicle, sensors)
