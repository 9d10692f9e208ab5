"""``insulator-rs inspect``: a whole single-flight inspection, wired from the command line.

This module is a composition root: it picks the adapters behind the flight loop's ports
and hands them to :class:`insulator_rs.flight.loop.FlightLoop`, which knows none of them.

* Vehicle: ``--vehicle sim`` (default) the in-process kinematic multirotor; ``--vehicle
  mavlink`` the MAVLink offboard client, by default against the simulated PX4 it starts on
  loopback (real UDP), or with ``--connection`` against a real PX4 or its SITL.
* Sensors: the simulator's camera and Mid-360, rendered from the scene (tower A by default)
  at the airframe's true pose; against an outside autopilot there is no simulator to ask,
  so that needs ``--sim-sensors`` (a SITL setup: the sensors render the scene at the pose
  the autopilot reports), or live sensors: ``--lidar mid360://HOST --camera SOURCE``
  (:mod:`insulator_rs.app.live_options`: a Livox Mid-360 and an OpenCV camera, stamped
  in the vehicle clock read from the autopilot's telemetry). A live
  flight is not scored against the scene (the scene is not what the sensors saw).
* Detector: by default the shipped YOLO network that fits the camera (``insulator-sim`` on
  the simulator's rendered frames, ``insulator-field`` on a real camera's), ``--detector`` another
  network, or ``--detector standin``: the simulator's ground-truth stand-in (true boxes, jittered).
* Sensor rig: the mission's ``[vehicle] rig`` file (camera calibration, T_b_c, T_b_l); the
  simulated airframe carries it (the shipped ``simulator`` rig when the mission names none).

After the flight the scorer compares the report with the scene (``score.json``): the flight
itself never sees ground truth.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from insulator_rs.app import live_options as cli_options
from insulator_rs.evaluation.scoring import score_flight, write_score
from insulator_rs.perception.photo_verdict import fit_tally
from insulator_rs.exceptions import ConfigError, SensorError, VehicleError
from insulator_rs.perception.photo_check import PHOTO_DETECT_CONF
from insulator_rs.ports.detector import STANDIN, BoxDetector, NetworkDetector, default_model, open_network_detector
from insulator_rs.flight.loop import FlightSettings
from insulator_rs.report.run_status import RunOutcome, RunStatus
from insulator_rs.flight.gc_pauses import startup_heap_frozen
from insulator_rs.flight.home import at_vehicle_home
from insulator_rs.flight.operator_abort import OperatorAbort, ReturnHandover, return_handover
from insulator_rs.flight.stall_watch import STALL_STACKS, StallWatch
from insulator_rs import bounds
from insulator_rs.mission.config import Mission, load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.planning.minsnap import TIME_ALLOCATIONS
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.mission.state_machine import POLICIES
from insulator_rs.report import check_out_folder, parse_out_folder
from insulator_rs.sim.flight_assembly import assemble_flight, simulated_ports
from insulator_rs.sim.kinematics import KinematicVehicle
from insulator_rs.sim.mission_airframe import LIMIT_HEADROOM, kinematic_vehicle  # noqa: F401 (their old home)
from insulator_rs.sim.wind import WindSpec
from insulator_rs.sim.sensors import (
    DETECT_SCALE,
    kinematic_true_pose,
    reported_pose,
    simulated_px4_true_pose,
)
from insulator_rs.sim.towers import load_tower
from insulator_rs.ports.vehicle import Vehicle

if TYPE_CHECKING:
    from insulator_rs.sim.px4 import SimulatedPx4

MISSIONS_DIR = Path(__file__).resolve().parents[1] / "missions"
MAX_MAVLINK_TIME_SCALE = 4.0  # the client's timeouts and the 20 Hz stream hold up to this speed-up


def charged(vehicle: KinematicVehicle, battery: float | None) -> KinematicVehicle:
    """``vehicle`` with its pack at ``battery`` (a fraction; None: as it is, full). The pack
    drains with time and distance (sim/kinematics.py)."""
    if battery is not None:
        vehicle.battery_fraction = battery
    return vehicle


def windy(vehicle: KinematicVehicle, wind: tuple[float, float], seed: int) -> KinematicVehicle:
    """``vehicle`` flying in ``wind`` (speed m/s, from-direction deg clockwise from north), with
    Dryden turbulence seeded by ``seed``."""
    if wind[0] > 0:
        vehicle.set_wind(WindSpec(speed=wind[0], from_deg=wind[1], seed=seed))
    return vehicle


def mavlink_vehicle(mission: Mission, seed: int, *, connection: str | None, time_scale: float,
                    signing_key: Path | None, gcs_port: int | None = None,
                    wind: tuple[float, float] = (0.0, 0.0),
                    battery: float | None = None) -> tuple[Vehicle, SimulatedPx4 | None]:
    """The MAVLink offboard client, and the simulated PX4 it flies when this started one: to
    the simulated PX4 (started here on loopback, flying :func:`kinematic_vehicle`, with PX4's
    GCS link on ``gcs_port`` when given) when ``connection`` is None, else (simulator None) to
    that autopilot with W's origin put at the tower base. ``battery``: the simulated pack's charge (None: full)."""
    from insulator_rs.mavlink import connect_vehicle
    from insulator_rs.sim.px4 import start_simulated_px4

    tower = mission.tower
    if connection is None:
        sim_options = {"vehicle": windy(charged(kinematic_vehicle(mission, seed), battery), wind, seed), "origin": (tower.lat, tower.lon, tower.alt),
                       "gcs_port": gcs_port}
        simulator, client = start_simulated_px4(time_scale=time_scale, signing_key=signing_key,
                                                sim_options=sim_options)
        return client, simulator
    vehicle = connect_vehicle(connection, time_scale=time_scale, signing_key=signing_key)
    try:
        vehicle.set_world_origin(tower.lat, tower.lon, tower.alt)
    except BaseException:
        vehicle.close()
        raise
    return vehicle, None


def load_network(model: str | None, *, live_camera: bool = False) -> NetworkDetector | None:
    """The YOLO network for detection events (a shipped model name or an ONNX file; default the
    shipped one that fits the camera); None for ``standin``. Raises ValueError naming ``--detector``."""
    if model is None:
        model = default_model(live_camera)
    if model == STANDIN:
        if live_camera:
            raise ValueError("--detector standin: the stand-in reads the simulator's ground truth; "
                             "a live camera needs a network")
        return None
    try:
        return open_network_detector(model)
    except ValueError as exc:  # ModelError included: missing, truncated or not a YOLO export
        raise ValueError(f"--detector: {exc}") from exc


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("inspect", help="fly a whole single-flight inspection (simulator or PX4)",
                              description="""\
Fly a whole single-flight inspection: take off, explore both sides of the tower, localize every
insulator with the camera and the LiDAR, photograph each one, cross over the top and land. The
report folder (--out) is written as the flight goes.

Vehicle: the built-in simulated multirotor (default); --vehicle mavlink flies the same mission
through a simulated PX4 over UDP; --connection flies a real PX4 or PX4 SITL.
Sensors: rendered from the built-in scene (tower A unless --scene); against an outside autopilot
add --sim-sensors (a SITL setup) or live sensors (--lidar and --camera).
Detector: the shipped network that fits the camera (insulator-sim on the simulator's frames,
insulator-field on a real camera's), another ONNX file, or 'standin' (the simulator's true boxes).
After a simulated flight, score.json compares the report with the scene's ground truth.""")
    p.add_argument("--scene", default="tower_a",
                   help="built-in scene name (tower_a, tower_b) or a scene TOML file (default tower_a)")
    p.add_argument("--mission", type=Path, default=None,
                   help="mission file (TOML/YAML); default: the example mission of a built-in scene")
    p.add_argument("--out", type=parse_out_folder, default=Path("inspection_report"),
                   help="report folder (created; one that holds files is refused unless --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the report in --out: the new run is written beside it and swapped in "
                        "when it ends, so the old report stays whole until then")
    p.add_argument("--method", type=LocalizationMethod, default=DEFAULT_METHOD,
                   choices=list(LocalizationMethod),
                   help="localization: the paper's four, or bounded (the LiDAR line, its ends from the boxes)")
    p.add_argument("--policy", default="immediate", choices=POLICIES,
                   help="buffering: visit at once (paper) or insert where cheapest")
    p.add_argument("--seed", type=bounds.option("--seed"), default=0,
                   help="random seed of the simulator (integer, 0 to 2^32-1): the same seed flies the same flight")
    p.add_argument("--wind", type=bounds.wind_option, default=(0.0, 0.0), metavar="SPEED[,DIR_DEG]",
                   help="mean wind in the simulator (m/s, from DIR_DEG clockwise from north; default "
                        "0), with seeded Dryden turbulence (the simulated airframe only)")
    p.add_argument("--detector", default=None,
                   help="a shipped model name or an ONNX file: the YOLO network run on the detection images "
                        "(default: the shipped one that fits the camera, insulator-sim for the simulator's, "
                        "insulator-field for a real one); 'standin' = the simulator's ground-truth stand-in "
                        "(true boxes, jittered), named as such in the report")
    p.add_argument("--time-allocation", default="pmm", choices=TIME_ALLOCATIONS,
                   help="min-snap segment times: pmm (point-mass proportions, default) or snap "
                        "(redistributed to minimise snap, Richter et al.; slower to plan)")
    p.add_argument("--detect-period", type=bounds.option("--detect-period"), default=1.0, help="s between detection events (default 1)")
    p.add_argument("--detect-scale", type=bounds.option("--detect-scale"), default=DETECT_SCALE,
                   help="detection camera resolution as a fraction of the rig camera's (default %(default)s)")
    p.add_argument("--photo-scale", type=bounds.option("--photo-scale"), default=1.0,
                   help="inspection photo resolution as a fraction of the rig camera's (default 1)")
    p.add_argument("--v-max", type=bounds.option("--v-max"), default=None, help="override the mission's velocity limits (m/s; default: the mission's [vehicle] limits)")
    p.add_argument("--a-max", type=bounds.option("--a-max"), default=None, help="override the mission's acceleration limits (m/s^2; default: the mission's [vehicle] limits)")
    p.add_argument("--max-flight-time", type=bounds.option("--max-flight-time"), default=1800.0, help="abort after this many s of flight (default %(default)g s)")
    p.add_argument("--sim-battery", type=bounds.option("--sim-battery"), default=None, metavar="FRACTION",
                   help="the simulated airframe's charge at take-off (fraction of the pack; default 1: full). "
                        "Its pack drains with time and distance (25 min hover); the mission comes back "
                        "before [inspection] battery_reserve is touched")
    p.add_argument("--no-obstacle-map", action="store_true",
                   help="check the route against the GPS-derived safety volumes only, not against the map "
                        "of what the LiDAR saw (the comparison: what the map buys; unsafe beside "
                        "anything the tower model does not hold)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--sim-camera-latency", type=bounds.option("--sim-camera-latency"), default=0.0,
                   help="s: the simulated camera's frames are stamped this long after their exposure (a late "
                        "camera, for 'insulator-rs calibrate time-offset'; default 0)")
    p.add_argument("--record", type=Path, default=None,
                   help="record the raw sensor stream (LiDAR, detection camera, pose, extrinsics) as ROS 2 "
                        "messages in this MCAP file (replay it with 'insulator-rs replay'; default: not recorded)")
    p.add_argument("--record-images", choices=("jpeg", "raw"), default="jpeg",
                   help="how --record stores the detection frames: jpeg (CompressedImage, small) or raw "
                        "(Image, lossless: a replay detects on exactly the flight's pixels)")
    p.add_argument("--vehicle", choices=("sim", "mavlink"), default=None,
                   help="sim: the in-process kinematic vehicle (default); mavlink: the MAVLink offboard "
                        "client, to the simulated PX4 it starts on loopback unless --connection is given")
    p.add_argument("--connection", default=None,
                   help="MAVLink connection of a real PX4 or its SITL, e.g. udpin:0.0.0.0:14540 or "
                        "/dev/ttyTHS1:921600 (implies --vehicle mavlink; needs --sim-sensors, or --lidar and --camera; "
                        "default: none, the in-process or simulated PX4)")
    p.add_argument("--sim-sensors", action="store_true",
                   help="with --connection: the camera and LiDAR are simulated from the scene at the pose the "
                        "autopilot reports (a SITL setup)")
    p.add_argument("--time-scale", type=float, default=None,
                   help=f"MAVLink only: speed-up of the simulated PX4 (default 1, at most "
                        f"{MAX_MAVLINK_TIME_SCALE:g}; give the SITL's speed factor with --connection)")
    p.add_argument("--signing-key", type=Path, default=None,
                   help="MAVLink only: file with the 32-byte MAVLink 2 signing key (both ends sign; default: unsigned)")
    p.add_argument("--gcs-port", type=int, default=None,
                   help="MAVLink, the simulated PX4 only: UDP port of its GCS link (as PX4 SITL's 18570+N), where a "
                        "ground station sees the mission's STATUSTEXT and photo markers (default: no GCS link)")
    cli_options.add_arguments(p)
    p.set_defaults(func=run)


def _vehicle_kind(args: argparse.Namespace) -> str:
    """Check the vehicle options together; "sim" or "mavlink"."""
    live = cli_options.check_arguments(args)  # --lidar/--camera: refused unless they can fly
    kind = args.vehicle or ("mavlink" if args.connection is not None else "sim")
    if kind == "sim":
        for flag, value in (("--connection", args.connection), ("--time-scale", args.time_scale),
                            ("--signing-key", args.signing_key)):
            if value is not None:
                raise ValueError(f"{flag}: only applies to --vehicle mavlink")
        if args.sim_sensors:
            raise ValueError("--sim-sensors: only applies with --connection")
        if args.gcs_port is not None:
            raise ValueError("--gcs-port: only applies to --vehicle mavlink (the simulated PX4)")
        return kind
    if args.sim_battery is not None and args.connection is not None:
        raise ValueError("--sim-battery: sets the charge of our simulated airframe; an outside autopilot has its "
                         "own (PX4 SIH: SIM_BAT_DRAIN, SIM_BAT_MIN_PCT)")
    if args.gcs_port is not None and (args.connection is not None or not 0 <= args.gcs_port <= 65535):
        raise ValueError("--gcs-port: a UDP port in [0, 65535] of the simulated PX4 (PX4 SITL has its own)")
    if args.time_scale is not None and not (math.isfinite(args.time_scale)
                                            and 0 < args.time_scale <= MAX_MAVLINK_TIME_SCALE):
        raise ValueError(f"--time-scale: must be in (0, {MAX_MAVLINK_TIME_SCALE:g}], got {args.time_scale}")
    if args.connection is not None:
        if not args.connection.strip():
            raise ValueError("--connection: must not be empty")
        if not args.sim_sensors and not live:
            raise ValueError("--connection: add --lidar and --camera (live sensors), or --sim-sensors to fly a "
                             "SITL autopilot with the sensors simulated from the scene")
    elif args.sim_sensors:
        raise ValueError("--sim-sensors: only applies with --connection (the built-in simulated PX4 "
                         "always has simulated sensors)")
    if args.signing_key is not None and not args.signing_key.is_file():
        raise ValueError(f"--signing-key: no such file: {args.signing_key}")
    return kind


def _with_limits(mission: Mission, v_max: float | None, a_max: float | None) -> Mission:
    if v_max is None and a_max is None:
        return mission
    v = mission.vehicle
    return replace(mission, vehicle=replace(
        v, v_max_horizontal=v_max or v.v_max_horizontal, v_max_vertical=v_max or v.v_max_vertical,
        a_max_horizontal=a_max or v.a_max_horizontal, a_max_vertical=a_max or v.a_max_vertical))


def _final_line(summary: dict[str, Any], score: dict[str, Any] | None, out: Path) -> str:
    fit_photos, with_fit = fit_tally(summary["photos"])
    photos = (f"{summary['insulators_inspected']} inspected, {len(with_fit)} with a fit photo, "
              f"{len(summary['photos'])} photos ({fit_photos} fit)")
    if score is None:  # a live flight
        return (f"{summary['status']}: flight {summary['flight_time_s']:.1f} s, "
                f"{summary['insulators_found']} insulators found, {photos}; report in {out}")
    mean = score["mean_error_m"]
    return (f"{summary['status']}: flight {summary['flight_time_s']:.1f} s, "
            f"{summary['insulators_found']} insulators found ({score['insulators_matched']} of "
            f"{score['insulators_in_scene']} matched), {photos}, mean error "
            f"{mean if mean is None else round(mean, 3)} m (scored after the flight); report in {out}")


def run(args: argparse.Namespace) -> int:
    # The numeric options were checked by argparse against insulator_rs.bounds.
    try:
        mavlink = _vehicle_kind(args) == "mavlink"
        tower = load_tower(args.scene)
        mission_path = args.mission
        if mission_path is None:
            mission_path = MISSIONS_DIR / f"{tower.spec.name}.toml"
            if not mission_path.is_file():
                raise ConfigError(f"--mission: scene {tower.spec.name!r} has no example mission; give one")
        mission = load_mission(mission_path)
        MissionGeometry.from_mission(mission)  # path and volumes: refuse before anything flies
        check_out_folder(args.out, overwrite=args.overwrite)
        network = load_network(args.detector, live_camera=getattr(args, "camera", None) is not None)
    except (ConfigError, ValueError) as exc:
        print(f"insulator-rs inspect: error: {exc}", file=sys.stderr)
        return 2
    if args.wind[0] > 0 and getattr(args, "connection", None) is not None:
        print("insulator-rs inspect: error: --wind: sets the wind of our simulated airframe; an outside "
              "autopilot flies in its own wind (PX4 SIH: its SIH wind parameters)", file=sys.stderr)
        return 2
    mission = _with_limits(mission, args.v_max, args.a_max)
    rig = mission.sensor_rig()
    if mavlink:
        try:
            vehicle, simulator = mavlink_vehicle(mission, args.seed, connection=args.connection,
                                                 time_scale=args.time_scale or 1.0, signing_key=args.signing_key,
                                                 gcs_port=args.gcs_port, wind=args.wind,
                                                 battery=args.sim_battery)
        except (VehicleError, ConfigError) as exc:  # no autopilot answering, a bad key file
            print(f"insulator-rs inspect: error: MAVLink vehicle: {exc}", file=sys.stderr)
            return 2
        pose = simulated_px4_true_pose(simulator) if simulator is not None else reported_pose(vehicle)
    else:
        vehicle = windy(charged(kinematic_vehicle(mission, args.seed), args.sim_battery), args.wind, args.seed)
        pose = kinematic_true_pose(vehicle)
    try:  # takeoff = "home": planned from where the vehicle stands, refused before anything flies
        mission = at_vehicle_home(mission, vehicle)
        MissionGeometry.from_mission(mission)
    except (ConfigError, ValueError) as exc:
        vehicle.close()
        print(f"insulator-rs inspect: error: {exc}", file=sys.stderr)
        return 2
    live = args.lidar is not None
    sensors: Any
    if live:
        try:
            sensors = cli_options.open_from_arguments(args, vehicle, rig)
        except SensorError as exc:
            vehicle.close()
            print(f"insulator-rs inspect: error: {exc}", file=sys.stderr)
            return 2
        assert network is not None  # live: the real-photo network by default; standin refused
        detector: BoxDetector = network
        photo_camera = rig.camera
        if rig.inspection is not None and rig.inspection.payload is not None:
            photo_camera = rig.inspection.camera  # the MAVLink payload photographs, at the shots' zoom
        elif rig.inspection is not None:
            # An inspection camera with no payload link has no live driver: the photos are the
            # detection camera's frames, so they are framed, checked and described
            # (CAMERA_INFORMATION) for that camera, not for a zoom that would never be applied.
            print("insulator-rs inspect: note: the rig's [inspection_camera] names no payload (its MAVLink "
                  "connection): the inspection photos are the detection camera's, framed for its lens",
                  file=sys.stderr)
            rig = replace(rig, inspection=None)
    else:
        ports = simulated_ports(tower.mesh, pose, rig, seed=args.seed, detect_scale=args.detect_scale,
                                photo_scale=args.photo_scale, camera_latency_s=args.sim_camera_latency,
                                network=network)
        sensors, detector, photo_camera = ports.sensors, ports.detector, ports.photo_camera
    settings = FlightSettings(method=args.method, policy=args.policy, detect_period=args.detect_period,
                              max_flight_time=args.max_flight_time, time_allocation=args.time_allocation,
                              quiet=args.quiet, obstacle_map=not args.no_obstacle_map)
    observer = None
    if mavlink:  # the pilot's view: STATUSTEXT and a MAVLink camera through the autopilot (mavlink/gcs.py)
        from insulator_rs.mavlink.gcs import CameraDescription, MavlinkGcsObserver

        lens = rig.inspection_camera()  # the photo camera: focal length and sensor size at full resolution
        camera = replace(CameraDescription.from_camera_model(lens.camera, pixel_pitch_um=lens.pixel_pitch_um,
                                                             vendor=lens.make, model=lens.model),
                         width_px=int(photo_camera.width), height_px=int(photo_camera.height))
        observer = MavlinkGcsObserver.on_vehicle(vehicle, camera=camera,
                                                 file_url_prefix=f"{Path(args.out).resolve().as_uri()}/")
    link_stats = getattr(vehicle, "link_stats", None) if mavlink else None  # the MAVLink adapter's counters
    recorder = None
    stall_watch = None
    if args.record is not None:  # recording wraps the ports: the flight does not know it is recorded
        from insulator_rs.recording.metadata import RECORD_NAME, FlightMetadata, takeoff_record
        from insulator_rs.recording.writer import McapRecorder

        recorder = McapRecorder(args.record, image_format=args.record_images)
        recorder.metadata(RECORD_NAME, FlightMetadata(
            mission_text=Path(mission_path).read_text(encoding="utf-8"), mission_suffix=Path(mission_path).suffix,
            mission_source=str(Path(mission_path).resolve()),  # absolute: a replay resolves its rig from there
            scene=str(Path(args.scene).resolve()) if Path(args.scene).is_file() else args.scene,
            # what the frames' stamps already carry: a replay applies a later calibration's difference
            camera_latency_s=repr(rig.camera_latency_s if live else 0.0),
            takeoff=takeoff_record(mission)).as_record())  # takeoff = "home": where the vehicle stood
    try:
        # the photo check reads the network's pieces of a close-up, low scores included, only where
        # the geometry puts the string (perception/photo_check.py PHOTO_DETECT_CONF)
        photo_detector = (None if network is None
                          else open_network_detector(str(network.network.path), conf=PHOTO_DETECT_CONF))
        flight = assemble_flight(mission, vehicle, sensors, detector, args.out, rig=rig, settings=settings,
                                 photo_camera=photo_camera, recorder=recorder, observer=observer,
                                 overwrite=args.overwrite, photo_detector=photo_detector)
        loop, vehicle, sensors = flight.loop, flight.vehicle, flight.sensors
        if mavlink:  # an outside autopilot fails safe when our setpoint thread stalls: watch for it
            stall_watch = loop.stall_watch = StallWatch(dump=Path(args.out) / STALL_STACKS).start()
        # the operator's abort: Ctrl-C / SIGTERM in the air, and the ground station's command
        operator = OperatorAbort(loop)
        if observer is not None:
            observer.on_abort_command(operator.request)
        code = 0
        # everything set up so far stays out of the collector's walks while the loop flies: a
        # full collection of it held the GIL past half a second on a loaded box (gc_pauses.py)
        with startup_heap_frozen():
            try:
                with operator.installed():
                    loop.fly()
            except ReturnHandover as exc:  # the second Ctrl-C in the air: PX4's Return, and out at once
                print(return_handover(loop, vehicle, exc.how), file=sys.stderr)
                return 130
            except KeyboardInterrupt:
                loop.outcome = RunOutcome(RunStatus.INTERRUPTED)
                code = 130
            except Exception:
                loop.outcome = RunOutcome(RunStatus.FAILED)
                loop.finish_report()
                raise
            # the flight is over (landed, aborted or interrupted): the recording is whole now, not
            # after the scoring below
            if recorder is not None:
                recorder.close()
            # now ground truth may be read
            if live:  # the sensors saw the world, not the scene: nothing to score against
                score = None
                summary = loop.finish_report()
            else:
                score = score_flight(loop.summary().as_dict(), tower, progress=None if args.quiet else print)
                summary = loop.finish_report(reference=np.array([t.center for t in tower.insulators]).reshape(-1, 3))
                write_score(args.out, score)
    finally:
        if stall_watch is not None:
            stall_watch.stop()
        if observer is not None:
            observer.close()
        vehicle.close()  # MAVLink: stops the threads and the simulated PX4 it started
        sensors.close()
        if recorder is not None:
            recorder.close()
    if loop.outcome.unsuccessful:  # aborted, or refused before arming
        code = 1
    print(_final_line(summary, score, args.out), file=sys.stdout)
    if link_stats is not None:  # what the link refused (strangers, garbage, bad signatures), by reason
        print(f"MAVLink link: {link_stats.describe()}", file=sys.stdout)
    return code
