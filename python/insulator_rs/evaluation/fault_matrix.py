"""The fault matrix (issue 19 item 6): every fault at every moment of the flight, in the simulator.

``python -m insulator_rs.evaluation.fault_matrix --out DIR`` (or ``insulator-rs eval faults``)
flies a scene (``--scene small``, the default: tower B's design cut to a 12 m body with one
cross-arm, a take-off, passes, two inspection detours, an over-the-top crossing and the way home
in 125 s; ``--scene tower_b``: the shipped tower B and its mission, 26 m with its cross-arms and
conductors, an 11-minute flight, so each cell costs minutes) once clean, reads the five moments
off that flight's own state log (``trajectory.csv``), then flies each fault from each moment:

* moments (s after arming): take-off (the climb, 1 m up), exploration (the middle of the longest
  pass), inspection (the middle of the first detour to an inspection waypoint), crossing (the
  middle of the over-the-top crossing), return (the middle of the way home and the landing);
* faults, each an adapter round a port (:mod:`insulator_rs.sim.faults`): link loss and client
  killed against our simulated PX4 over real UDP (``--vehicle mavlink``: PX4's own failsafes,
  COM_OF_LOSS_T, COM_OBL_RC_ACT, RTL_RETURN_ALT, NAV_DLL_ACT, take over); the LiDAR silent, the
  camera frozen, the detector raising, the pack dropping to its reserve, GPS (the position
  estimate) lost and the operator's abort in process; "process killed": the companion is
  ``insulator-rs inspect --connection`` in a process of its own, flying our simulated PX4 started
  here, ended by a real SIGKILL (``kill -9``);
* the payload's faults (:mod:`insulator_rs.evaluation.payload_faults`): the flight against our
  simulated PX4 photographs through the simulated MAVLink gimbal-and-zoom payload, whose capture
  never answers, gimbal jams at its limit, zoom is refused, downloads stop halfway, or which falls
  silent, from the moment on; each cell says which insulators have no photo and why, and the
  setpoint stream's longest gap while the loop waited for the failing shots;
* the MAVLink cells have a ground station on PX4's GCS link, relayed by the companion
  (:class:`~insulator_rs.sim.px4_gcs.RelayedGroundStation`): the companion sets NAV_DLL_ACT to
  Return, and the link lost or the companion dead takes the ground station's link down too, so
  PX4's GCS connection loss returns where no offboard loss fires (the take-off climb).

For each cell, from the scene's TRUE geometry (its mesh: steel, insulators, fittings and
conductors; not the mission's boxes) and the airframe's TRUE trajectory (the simulator's, up to
the landing, whoever flew it): the minimum clearance, against the mission's ``safety_margin``;
how the flight ended (landed by our route, by PX4's, or still flying); what ``summary.json`` says;
whether the recording (``--record``, MCAP) holds every message written to it (the client killed: every
message flushed before the kill, the recorder flushing every second). The GPS loss row samples one
moment of each phase; :func:`descent_exposure` measures PX4's descent in place (its answer to a lost
position) from every 0.5 s of the clean flight, per phase, against the same mesh and margin. Writes
``fault_matrix.md`` (the table), ``fault_matrix.json`` and ``fault_matrix.png`` (cells coloured by
clearance) in ``--out``, one line per cell as it goes.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time as wallclock
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.evaluation.payload_faults import PAYLOAD_FAULTS, max_setpoint_gap, payload_table, photos_missing
from insulator_rs.exceptions import ClientKilled
from insulator_rs.ports.vehicle import VehicleState

PACKAGE = Path(__file__).resolve().parents[1]
FAULTS = ("link loss", "LiDAR silent", "camera frozen", "detector error", "low battery", "GPS loss",
          "operator abort", "client killed", "process killed", *PAYLOAD_FAULTS)
MOMENTS = ("take-off", "exploration", "inspection", "crossing", "return")
#: the faults flown against our simulated PX4 over UDP: the companion's link or process is the fault
MAVLINK_FAULTS = ("link loss", "client killed", "process killed")
#: what summary.json must name for each fault (its status, abort reason or failsafe), lower case
REPORT_WORDS = {"link loss": ("heartbeat", "link"), "LiDAR silent": ("lidar",), "camera frozen": ("camera",),
                "detector error": ("detector",), "low battery": ("battery",), "GPS loss": ("position",),
                "operator abort": ("operator",), "client killed": ("running",), "process killed": ("running",),
                # the payload's: the insulators without a photo, and the fault each attempt met
                **{name: (fault.value,) for name, fault in PAYLOAD_FAULTS.items()}}
SURFACE_STEP = 0.05  # m between the points sampled on the scene's surfaces (the clearance's resolution)
SAMPLE_CELL = 0.01  # m: the samples are kept one a cube of this side (its centre; the bound grows by its half-diagonal)
LOW_BATTERY_ABOVE_RESERVE = 0.01  # the pack drops to 1 % above the mission's reserve
TIME_SCALE = 4.0  # the simulated PX4's speed-up (the client's limit)
LANDING_WAIT = 300.0  # s of vehicle time to watch PX4 (or the autopilot's landing) bring it down
HOVER_WAIT = 30.0  # s of vehicle time in HOLD after which the autopilot is taken to hover for the pilot
WATCH_PERIOD = 0.02  # wall s between looks at our simulated PX4 once the companion is gone
FLIGHT_ARGS = {"detect_period": 0.5, "detect_scale": 0.2, "photo_scale": 0.2, "seed": 0}
CLIMB_HEIGHT = 1.0  # m above the take-off point: the take-off moment (the climb under way)
PROCESS_START_WAIT = 120.0  # wall s for the companion process to start, set PX4 up and arm


@dataclass
class Cell:
    """One fault at one moment, measured (see the module docstring)."""

    fault: str
    moment: str
    at_s: float  # s after arming the fault began
    vehicle: str  # "in process" or "simulated PX4 (UDP)"
    clearance_m: float  # minimum distance of the true trajectory to the scene's structure
    nearest: str  # the kind of structure nearest then
    max_altitude_m: float
    ended: str  # "landed: our route", "landed: PX4 RTL", ...
    status: str  # summary.json's status
    reason: str  # summary.json's abort reason or failsafe, else ""
    report_names_fault: bool
    recording: str  # "N of N messages" read back
    recording_intact: bool
    flight_s: float
    wall_s: float
    photos_missing: str = ""  # the insulators without a fit photo, and why (summary.json's photo checks)
    max_setpoint_gap_s: float | None = None  # the offboard setpoint stream's longest gap (None: in process)


# -- the scene -----------------------------------------------------------------------------------
#: the scenes the matrix flies: name -> what the table says of it
SCENES = {"small": "small (tower B's design, 12 m body, one cross-arm)",
          "tower_b": "tower B (26 m, its cross-arms and conductors, the shipped mission)"}


def scene_files(name: str, folder: Path) -> tuple[Path, Path]:
    """The scene and mission files of the matrix's scene ``name`` (one of :data:`SCENES`); the
    small scene's are written in ``folder``."""
    if name == "small":
        return small_scene(folder, PACKAGE / "scenes", PACKAGE / "missions")
    if name == "tower_b":
        return PACKAGE / "scenes" / "tower_b.toml", PACKAGE / "missions" / "tower_b.toml"
    raise ValueError(f"scene: {name!r} is not one of {', '.join(SCENES)}")


def small_scene(folder: Path, scenes: Path, missions: Path) -> tuple[Path, Path]:
    """Tower B's design cut down to a 12 m body with one cross-arm (two insulators), and its
    mission (the passes 6 m from the line, 3 m/s): the files written in ``folder``."""
    s = (scenes / "tower_b.toml").read_text(encoding="utf-8")
    s = s.replace('name = "tower_b"', 'name = "small_tower"')
    s = s.replace("height = 26.0\nbase_width = 5.6", "height = 12.0\nbase_width = 3.0")
    s = s.replace("panels = 9", "panels = 4").replace("peak_height = 2.5", "peak_height = 1.5")
    i, k = s.index("[[cross_arms]]"), s.index("[insulators]")
    s = s[:i] + "[[cross_arms]]\nheight = 10.0\nreach = 3.0\ndepth = 1.2\nwidth = 1.0\n\n" + s[k:]
    m = (missions / "tower_b.toml").read_text(encoding="utf-8")
    for a, b in (("max_height = 28.5", "max_height = 13.5"), ("max_width = 9.0", "max_width = 6.0"),
                 ("pass_spacing = 8.0", "pass_spacing = 10.0"), ("standoff = 8.0", "standoff = 6.0"),
                 ("v_max_horizontal = 1.0", "v_max_horizontal = 3.0"),
                 ("a_max_horizontal = 3.0", "a_max_horizontal = 6.0"),
                 ("v_max_vertical = 1.0", "v_max_vertical = 2.0"),
                 ("a_max_vertical = 3.0", "a_max_vertical = 4.0")):
        if a not in m:
            raise ValueError(f"{missions / 'tower_b.toml'}: no {a!r} to cut the small mission from")
        m = m.replace(a, b)
    folder.mkdir(parents=True, exist_ok=True)
    scene, mission = folder / "small_tower.toml", folder / "small_mission.toml"
    scene.write_text(s, encoding="utf-8")
    mission.write_text(m, encoding="utf-8")
    return scene, mission


class Structure:
    """The scene's structure (every triangle but the ground's) sampled every SURFACE_STEP m, for
    the clearance of a trajectory: the distance to the nearest sample less the sampling's worst
    case (a point of a triangle is at most ``bound`` from a sample), so never more than the truth."""

    def __init__(self, mesh: Any) -> None:
        from scipy.spatial import cKDTree

        keep = np.array([mesh.instances[int(i)].kind != "ground" if int(i) in mesh.instances else True
                         for i in mesh.instance_ids])
        tri = mesh.vertices[mesh.triangles[keep]]  # (T, 3, 3)
        kinds = np.array([mesh.instances[int(i)].kind if int(i) in mesh.instances else "other"
                          for i in mesh.instance_ids[keep]])
        points, labels = [], []
        for (a, b, c), kind in zip(tri, kinds):
            n = max(1, int(math.ceil(max(np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b))
                                     / SURFACE_STEP)))
            u, v = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
            sel = u + v <= n
            w1, w2 = u[sel] / n, v[sel] / n
            points.append(a + np.outer(w1, b - a) + np.outer(w2, c - a))
            labels.extend([kind] * int(sel.sum()))
        # one sample per SAMPLE_CELL cube, at its centre: tower B's conductors (2.2 cm across) and
        # sheds give 6.4 M samples in 0.76 M such cells, and the crowd made each search ~0.8 ms
        cells, first = np.unique(np.floor(np.concatenate(points) / SAMPLE_CELL).astype(np.int64), axis=0,
                                 return_index=True)
        self.points = (cells + 0.5) * SAMPLE_CELL
        self.labels = np.array(labels)[first]
        self.tree = cKDTree(self.points)
        # a point of a grid cell to its nearest corner, and that corner to its cube's centre
        self.bound = SURFACE_STEP / math.sqrt(3.0) + SAMPLE_CELL * math.sqrt(3.0) / 2

    def clearance(self, positions: np.ndarray) -> tuple[float, str]:
        """(minimum clearance in m, the kind of structure nearest there) along ``positions``."""
        d, kinds = self.clearances(positions)
        j = int(np.argmin(d))
        return float(d[j]), str(kinds[j])

    def clearances(self, positions: np.ndarray, upto: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """The clearance (m, never more than the truth) of each of ``positions`` (N, 3), and the
        kind of structure nearest each; with ``upto`` (m), a position farther than that from every
        sample gets inf and the kind "" (the search stops there: a dense mesh is slow to search
        from far away)."""
        d, k = self.tree.query(np.asarray(positions, dtype=np.float64).reshape(-1, 3), distance_upper_bound=upto)
        found = k < len(self.labels)
        kinds = np.full(len(k), "", dtype=self.labels.dtype)
        kinds[found] = self.labels[k[found]]
        return np.maximum(0.0, d - self.bound), kinds


# -- a descent in place from every moment ---------------------------------------------------------
DESCENT_STEP = 0.1  # m between the points sampled down a descent column (half of it is subtracted)
DESCENT_EVERY = 0.5  # s of the clean flight between the descents measured
DESCENT_RANGE = 10.0  # m: a descent farther than this from the structure is reported as this far


def descent_clearances(structure: Structure, positions: np.ndarray, ground_z: float) -> tuple[np.ndarray, np.ndarray]:
    """For each W position (N, 3): the clearance of a vertical descent from there down to
    ``ground_z`` (what PX4 flies when the position estimate is lost: its LAND/Descend in place),
    i.e. the least distance from that column to the structure, less half the column's sampling
    step (a point of the column is at most that far from a sample: never more than the truth),
    at most DESCENT_RANGE; and the kind of structure nearest each column ("" beyond that range)."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    columns = [np.column_stack([np.full(len(z), x), np.full(len(z), y), z])
               for x, y, z in ((q[0], q[1], np.append(np.arange(q[2], ground_z, -DESCENT_STEP), ground_z))
                               for q in p)]
    starts = np.cumsum([0] + [len(c) for c in columns[:-1]])
    d, kinds = structure.clearances(np.concatenate(columns), upto=DESCENT_RANGE + structure.bound + DESCENT_STEP)
    d = np.minimum(np.maximum(0.0, d - DESCENT_STEP / 2), DESCENT_RANGE)
    nearest = np.array([kinds[a + int(np.argmin(d[a:a + len(c)]))] for a, c in zip(starts, columns)])
    return np.minimum.reduceat(d, starts), nearest


def descent_exposure(trajectory_csv: Path, structure: Structure, margin: float) -> dict[str, dict[str, Any]]:
    """Per phase of a clean flight (its state log's states, in order of first appearance): how
    long it lasted (s), for how long a descent in place from where the vehicle was would come
    within ``margin`` of the structure (s, sampled every DESCENT_EVERY s), and the least such
    descent's clearance, the structure nearest it and when (s after arming). The matrix's GPS
    loss row samples one moment of each phase; this is every moment of it. The positions are the
    state log's (the vehicle's estimate: the in-process airframe's odometry, cm from the truth)."""
    import csv

    with trajectory_csv.open(encoding="utf-8") as f:
        rows = [(float(r["time_s"]), float(r["x_m"]), float(r["y_m"]), float(r["z_m"]), r["state"])
                for r in csv.DictReader(f)]
    if not rows:
        raise ValueError(f"{trajectory_csv}: the clean flight's state log is empty")
    ground_z = rows[0][3]
    picked, next_t = [], -math.inf
    for row in rows:
        if row[0] >= next_t:
            picked.append(row)
            next_t = row[0] + DESCENT_EVERY
    d, kinds = descent_clearances(structure, np.array([r[1:4] for r in picked]), ground_z)
    out: dict[str, dict[str, Any]] = {}
    for (t, *_, state), c, kind in zip(picked, d, kinds):
        e = out.setdefault(state, {"seconds": 0.0, "within_margin_s": 0.0, "min_clearance_m": math.inf,
                                   "nearest": "", "at_s": 0.0})
        e["seconds"] += DESCENT_EVERY
        e["within_margin_s"] += DESCENT_EVERY if c < margin else 0.0
        if c < e["min_clearance_m"]:
            e.update(min_clearance_m=round(float(c), 2), nearest=str(kind), at_s=round(t, 1))
    return out


# -- the moments ----------------------------------------------------------------------------------
def moments_from(trajectory_csv: Path) -> dict[str, float]:
    """The five moments (s after arming) from a clean flight's state log (see the module docstring)."""
    import csv

    with trajectory_csv.open(encoding="utf-8") as f:
        rows = [(float(r["time_s"]), float(r["z_m"]), r["state"]) for r in csv.DictReader(f)]
    runs: list[tuple[str, float, float]] = []  # (state, first s, last s)
    for t, _, state in rows:
        if runs and runs[-1][0] == state:
            runs[-1] = (state, runs[-1][1], t)
        else:
            runs.append((state, t, t))

    def middle(state: str, longest: bool = False) -> float:
        spans = [(b - a, (a + b) / 2) for s, a, b in runs if s == state]
        if not spans:
            raise ValueError(f"{trajectory_csv}: the clean flight has no {state!r} phase")
        return round((max(spans) if longest else spans[0])[1], 1)

    z0 = rows[0][1]
    climb = next(t for t, z, s in rows if s == "idle" and z - z0 >= CLIMB_HEIGHT)
    return {"take-off": round(climb, 1), "exploration": middle("explore", longest=True),
            "inspection": middle("inspect"), "crossing": middle("cross"), "return": middle("finish")}


# -- one cell -------------------------------------------------------------------------------------
@dataclass
class Setup:
    """What every cell flies: the scene and mission files, the built scene, the structure."""

    scene: Path
    mission: Path
    tower: Any
    structure: Structure
    margin: float


def _readable_messages(path: Path) -> int:
    """Messages readable from an MCAP file (a complete one, or one cut short: up to the cut)."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    n = 0
    with path.open("rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                n += isinstance(record, Message)
        except Exception:  # noqa: BLE001 - the cut: everything before it was counted
            pass
    return n


def fly_cell(setup: Setup, fault: str | None, moment: str, at: float, out: Path,
             say: Callable[[str], None] = lambda _: None) -> Cell:
    """Fly ``fault`` from ``at`` s after arming (None: the clean flight) into ``out``; measure it."""
    if fault == "process killed":
        return fly_process_cell(setup, moment, at, out, say)
    from insulator_rs.sim.mission_airframe import kinematic_vehicle
    from insulator_rs.flight.loop import FlightLoop, FlightSettings
    from insulator_rs.mission.config import load_mission
    from insulator_rs.recording.writer import McapRecorder
    from insulator_rs.sim import faults as F
    from insulator_rs.sim.flight_assembly import assemble_flight, simulated_ports
    from insulator_rs.sim.sensors import kinematic_true_pose, simulated_px4_true_pose

    wall0 = wallclock.perf_counter()
    mission = load_mission(setup.mission)
    rig = mission.sensor_rig()
    seed = int(FLIGHT_ARGS["seed"])
    airframe_vehicle = kinematic_vehicle(mission, seed)
    mavlink = fault in MAVLINK_FAULTS or fault in PAYLOAD_FAULTS  # the payload's: PX4 streams while a shot waits
    simulator: Any = None
    ground_station: Any = None
    base: Any
    if mavlink:
        from insulator_rs.mavlink.client import MavlinkVehicle

        simulator, ground_station = _simulated_px4(mission, airframe_vehicle)
        host, port = simulator.address
        # the client does not own the simulator: a killed client leaves PX4 flying
        base = MavlinkVehicle(f"udpout:{host}:{port}", time_scale=TIME_SCALE)
        airframe: Callable[[Callable[[Any], Any]], Any] = simulator.with_vehicle
        pose = simulated_px4_true_pose(simulator)
    else:
        base = airframe_vehicle

        def airframe(f: Callable[[Any], Any]) -> Any:
            return f(airframe_vehicle)
        pose = kinematic_true_pose(airframe_vehicle)
    truth: list[np.ndarray] = []

    def look(_: VehicleState | None = None) -> None:
        truth.append(airframe(lambda v: v.model.position.copy()))

    clock = F.FaultClock()
    loop_ref: list[FlightLoop] = []
    actions: dict[str, Callable[[], Callable[[], None]]] = {
               "link loss": lambda: _with_the_relay(ground_station, F.link_loss(simulator)),
               "client killed": lambda: _with_the_relay(ground_station, F.kill_client(base)),
               "GPS loss": lambda: F.gps_loss(airframe),
               "low battery": lambda: F.battery_drop(
                   airframe, mission.inspection.battery_reserve + LOW_BATTERY_ABOVE_RESERVE),
               "operator abort": lambda: (lambda: loop_ref[0].request_abort())}
    timed = [F.TimedAction(at, fault, actions[fault]())] if fault in actions else []
    out.mkdir(parents=True, exist_ok=True)
    recorder = McapRecorder(out / "flight.mcap")
    ports = simulated_ports(setup.tower.mesh, pose, rig, seed=seed, detect_scale=FLIGHT_ARGS["detect_scale"],
                            photo_scale=FLIGHT_ARGS["photo_scale"])
    sensors: Any = F.FaultySensors(ports.sensors, clock, lidar_silent_at=at if fault == "LiDAR silent" else None,
                                   camera_frozen_at=at if fault == "camera frozen" else None)
    payload: Any = None
    if fault in PAYLOAD_FAULTS:
        from insulator_rs.evaluation.payload_faults import photograph_through_payload

        payload = photograph_through_payload(
            sensors, inspection=rig.inspection_camera(), mesh=setup.tower.mesh, origin=mission.tower,
            true_pose=pose, clock=lambda: airframe(lambda v: float(v.clock.now)),
            vehicle_pose=lambda: base.state().T_w_b, photo_scale=FLIGHT_ARGS["photo_scale"],
            time_scale=TIME_SCALE, seed=seed)
        sensors = payload.sensors
        timed = [F.TimedAction(at, fault, payload.fault(fault))]
    detector: Any = ports.detector
    if fault == "detector error":
        detector = F.FailingDetector(detector, at, lambda: clock.elapsed(base.state().time))
    settings = FlightSettings(detect_period=FLIGHT_ARGS["detect_period"], quiet=True)
    # the faults round the vehicle stay out of the recording: it holds what the autopilot reported
    loop = assemble_flight(mission, base, sensors, detector, out / "report", rig=rig, settings=settings,
                           photo_camera=ports.photo_camera, recorder=recorder,
                           outer_vehicle=lambda recorded: F.FaultyVehicle(recorded, clock, timed, watch=look)).loop
    loop_ref.append(loop)
    killed = False
    try:
        look()
        try:
            loop.fly()
            loop.finish_report()
        except ClientKilled:
            killed = True  # as kill -9: no report written after, the recorder never closed
            saved = (out / "flight.mcap").read_bytes()  # what the file held at the kill
        if not killed:
            recorder.close()
        ended = _watch_landing(airframe, look, base if not mavlink else None, setup, loop, killed)
    finally:
        if payload is not None:
            payload.close()
        if mavlink:
            if not killed:
                base.close()
            ground_station.close()
            simulator.stop()
    if killed:
        (out / "flight.mcap").write_bytes(saved)
    written, durable = sum(recorder.counts.values()), recorder.durable
    read = _readable_messages(out / "flight.mcap")
    summary = json.loads((out / "report" / "summary.json").read_text(encoding="utf-8"))
    reason = _reported_reason(summary)
    missing = photos_missing(summary)
    said = f"{summary['status']} {reason}" + (f" {missing}" if fault in PAYLOAD_FAULTS else "")
    said = said.lower()
    clearance, nearest = setup.structure.clearance(np.array(truth))
    cell = Cell(fault=fault or "none", moment=moment, at_s=at,
                vehicle="simulated PX4 (UDP)" if mavlink else "in process",
                clearance_m=round(clearance, 2), nearest=nearest,
                max_altitude_m=round(float(np.max(np.array(truth)[:, 2])), 1), ended=ended,
                status=summary["status"], reason=reason,
                report_names_fault=fault is None or any(w in said for w in REPORT_WORDS[fault]),
                recording=f"{read} of {written} messages" + (f" ({durable} flushed before the kill)" if killed else ""),
                recording_intact=read >= (durable if killed else written),
                flight_s=round(float(summary["flight_time_s"]), 1), wall_s=round(wallclock.perf_counter() - wall0, 1),
                photos_missing=missing, max_setpoint_gap_s=max_setpoint_gap(summary))
    say(_one_line(cell))
    return cell


def _reported_reason(summary: dict[str, Any]) -> str:
    """What summary.json gives as the cause: the abort's reason, else the failsafe's, else ""."""
    return str((summary.get("abort") or {}).get("reason") or (summary.get("failsafe") or {}).get("reason") or "")


def _one_line(cell: Cell) -> str:
    return (f"{cell.fault:>14} @ {cell.moment:<11} ({cell.at_s:5.1f} s): clearance {cell.clearance_m:5.2f} m "
            f"({cell.nearest}), {cell.ended}; {cell.status[:70]}; recording {cell.recording}; {cell.wall_s:.0f} s")


def _simulated_px4(mission: Any, airframe_vehicle: Any) -> tuple[Any, Any]:
    """Our simulated PX4 flying ``airframe_vehicle`` (started), with a GCS link and a ground
    station on it relayed by the companion (started): PX4 arms with NAV_DLL_ACT set."""
    from insulator_rs.sim.px4 import SimulatedPx4
    from insulator_rs.sim.px4_gcs import RelayedGroundStation

    origin = (mission.tower.lat, mission.tower.lon, mission.tower.alt)
    simulator = SimulatedPx4(time_scale=TIME_SCALE, vehicle=airframe_vehicle, origin=origin, gcs_port=0)
    gcs_link = simulator.gcs
    if gcs_link is None:
        raise RuntimeError("the simulated PX4 was started without its GCS link")
    return simulator.start(), RelayedGroundStation(gcs_link.address).start()


def _with_the_relay(ground_station: Any, fault: Callable[[], None]) -> Callable[[], None]:
    """``fault`` (the companion's link lost, the companion dead) takes the ground station's link,
    relayed by the companion, down with it."""
    def both() -> None:
        ground_station.cut()
        fault()
    return both


def fly_process_cell(setup: Setup, moment: str, at: float, out: Path,
                     say: Callable[[str], None] = lambda _: None) -> Cell:
    """The companion as a process of its own (``python -m insulator_rs.app.cli inspect
    --connection``, the sensors simulated from the scene at the pose PX4 reports) flying our
    simulated PX4 started here; ``at`` s after PX4 armed (the take-off moment: once the vehicle is
    :data:`CLIMB_HEIGHT` m up) it is sent SIGKILL (``kill -9``: no handler, no report written
    after, the recorder never closed) and the ground station it relays goes with it; PX4's
    failsafes fly the rest. Measured as :func:`fly_cell` measures."""
    import os
    import signal
    import subprocess

    from insulator_rs.mission.config import load_mission
    from insulator_rs.sim.mission_airframe import kinematic_vehicle

    wall0 = wallclock.perf_counter()
    mission = load_mission(setup.mission)
    simulator, ground_station = _simulated_px4(mission, kinematic_vehicle(mission, int(FLIGHT_ARGS["seed"])))
    host, port = simulator.address
    out.mkdir(parents=True, exist_ok=True)
    report, recording = out / "report", out / "flight.mcap"
    command = [sys.executable, "-m", "insulator_rs.app.cli", "inspect", "--scene", str(setup.scene),
               "--mission", str(setup.mission), "--out", str(report), "--record", str(recording),
               "--connection", f"udpout:{host}:{port}", "--sim-sensors", "--time-scale", f"{TIME_SCALE:g}",
               "--detector", "standin", "--quiet", "--overwrite",
               *(a for k, v in FLIGHT_ARGS.items() for a in (f"--{k.replace('_', '-')}", str(v)))]
    truth: list[np.ndarray] = []

    def look() -> None:
        truth.append(simulator.with_vehicle(lambda v: v.model.position.copy()))

    def vehicle_now() -> tuple[bool, float, float]:
        return simulator.with_vehicle(lambda v: (bool(v.armed), float(v.clock.now),
                                                 float(v.model.position[2] - v.home[2])))

    log = (out / "companion.log").open("w", encoding="utf-8")
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    killed = False
    try:
        armed_at: float | None = None
        deadline = wallclock.monotonic() + PROCESS_START_WAIT
        while process.poll() is None:
            look()
            armed, now, height = vehicle_now()
            if armed_at is None and armed:
                armed_at = now
                deadline = wallclock.monotonic() + 2 * LANDING_WAIT / TIME_SCALE
            # the take-off moment is the climb under way: over MAVLink from another process the
            # take-off command comes later after arming than in process (its round trips)
            due = height >= CLIMB_HEIGHT if moment == "take-off" else armed_at is not None and now - armed_at >= at
            if armed_at is not None and due:
                os.kill(process.pid, signal.SIGKILL)
                ground_station.cut()
                killed, at = True, round(now - armed_at, 1)  # when it came, by PX4's clock
                break
            if wallclock.monotonic() > deadline:
                raise RuntimeError(f"the companion process did not reach {at:g} s after arming in time (see "
                                   f"{out / 'companion.log'})")
            wallclock.sleep(WATCH_PERIOD)
        process.wait(timeout=30.0)
        ended = _watch_landing(simulator.with_vehicle, look, None, setup, None, killed)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        log.close()
        ground_station.close()
        simulator.stop()
    summary = json.loads((report / "summary.json").read_text(encoding="utf-8"))
    reason = _reported_reason(summary)
    read = _readable_messages(recording) if recording.is_file() else 0
    clearance, nearest = setup.structure.clearance(np.array(truth))
    cell = Cell(fault="process killed", moment=moment, at_s=at, vehicle="simulated PX4 (UDP), companion process",
                clearance_m=round(clearance, 2), nearest=nearest,
                max_altitude_m=round(float(np.max(np.array(truth)[:, 2])), 1),
                ended=ended if killed else f"not killed: the process ended first (exit code {process.returncode})",
                status=summary["status"], reason=reason,
                report_names_fault=any(w in f"{summary['status']} {reason}".lower()
                                       for w in REPORT_WORDS["process killed"]),
                recording=f"{read} messages read back (the process killed: what it flushed)",
                recording_intact=killed and process.returncode == -signal.SIGKILL and read > 0,
                flight_s=round(float(summary["flight_time_s"]), 1), wall_s=round(wallclock.perf_counter() - wall0, 1))
    say(_one_line(cell))
    return cell


def _watch_landing(airframe: Callable[[Callable[[Any], Any]], Any], look: Callable[[], None],
                   in_process: Any, setup: Setup, loop: Any, killed: bool) -> str:
    """After the companion's flight: let the autopilot finish (its failsafe, its landing) while
    the true position is logged, up to LANDING_WAIT s of vehicle time; how it ended."""
    from insulator_rs.exceptions import VehicleFailsafe

    def status() -> tuple[bool, bool, str, float]:
        return airframe(lambda v: (bool(v.landed), bool(v.armed), str(v.mode.value), float(v.clock.now)))

    landed, armed, mode, t0 = status()
    modes = {mode}
    now, wall_end = t0, wallclock.monotonic() + 2 * LANDING_WAIT / TIME_SCALE
    hover_since = t0  # a hover (HOLD) nobody ends: the pilot's, after HOVER_WAIT s it is the end
    while not (landed and not armed) and now - t0 < LANDING_WAIT and wallclock.monotonic() < wall_end:
        if mode != "HOLD":
            hover_since = now
        elif now - hover_since > HOVER_WAIT:
            break
        if in_process is not None:
            try:
                in_process.advance(0.05)
            except VehicleFailsafe:
                pass
        else:
            wallclock.sleep(WATCH_PERIOD)
        look()
        landed, armed, mode, now = status()
        modes.add(mode)
    who = "PX4" if killed or loop.failsafe is not None else "our route" if loop.abort_route is not None \
        else "handed to the pilot" if loop.handed_over is not None else "the plan"
    px4_mode = next((m for m in ("AUTO_RTL", "RTL", "AUTO_LAND", "LAND") if m in modes), None) \
        if who == "PX4" else None
    if landed:
        return f"landed: {who}" + (f" ({px4_mode})" if px4_mode else "")
    return f"in the air: {who} ({mode})"


# -- the matrix -----------------------------------------------------------------------------------
def run_matrix(out: Path, faults: Sequence[str] = FAULTS, moments: Sequence[str] = MOMENTS,
               say: Callable[[str], None] = print, scene_name: str = "small") -> dict[str, Any]:
    """The clean flight, then every (fault, moment) cell; results written in ``out``."""
    from insulator_rs.mission.config import load_mission
    from insulator_rs.sim.towers import load_tower

    if scene_name not in SCENES:
        raise ValueError(f"scene: {scene_name!r} is not one of {', '.join(SCENES)}")
    for name in faults:
        if name not in FAULTS:
            raise ValueError(f"fault: {name!r} is not one of {', '.join(FAULTS)}")
    for name in moments:
        if name not in MOMENTS:
            raise ValueError(f"moment: {name!r} is not one of {', '.join(MOMENTS)}")
    import importlib.util

    if importlib.util.find_spec("mcap") is None:  # every cell's recording is read back
        raise ValueError("the fault matrix records each cell and reads it back: install the bags extra "
                         "(pip install 'insulator_rs[bags]')")
    wall0 = wallclock.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    scene, mission = scene_files(scene_name, out / "scene")
    tower = load_tower(str(scene))
    setup = Setup(scene, mission, tower, Structure(tower.mesh), load_mission(mission).inspection.safety_margin)
    flights = out / "flights"
    clean = fly_cell(setup, None, "clean", math.inf, flights / "clean", say)
    moments_s = moments_from(flights / "clean" / "report" / "trajectory.csv")
    say(f"moments (s after arming): {moments_s}")
    descent = descent_exposure(flights / "clean" / "report" / "trajectory.csv", setup.structure, setup.margin)
    say("a descent in place from each phase (within the margin / phase): "
        + ", ".join(f"{k} {v['within_margin_s']:.0f}/{v['seconds']:.0f} s" for k, v in descent.items()))
    cells = [fly_cell(setup, f, m, moments_s[m], flights / f"{f.replace(' ', '_')}-{m}", say)
             for f in faults for m in moments]
    result = {"scene": SCENES[scene_name], "margin_m": setup.margin,
              "surface_step_m": SURFACE_STEP, "moments_s": moments_s, "clean": asdict(clean),
              "descent_in_place": descent,
              "cells": [asdict(c) for c in cells], "below_margin": sum(c.clearance_m < setup.margin for c in cells),
              "not_landed": sum(not c.ended.startswith("landed") for c in cells),
              "wall_s": round(wallclock.perf_counter() - wall0, 1)}
    (out / "fault_matrix.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    (out / "fault_matrix.md").write_text(markdown(result), encoding="utf-8")
    plot(result, out / "fault_matrix.png")
    return result


def markdown(result: dict[str, Any]) -> str:
    """The matrix as markdown: clearance / end per cell, then one line per cell of what the report said."""
    cells = result["cells"]
    moments = [m for m in MOMENTS if any(c["moment"] == m for c in cells)]
    faults = [f for f in FAULTS if any(c["fault"] == f for c in cells)]
    by = {(c["fault"], c["moment"]): c for c in cells}
    lines = ["| fault | " + " | ".join(f"{m} ({result['moments_s'][m]:.0f} s)" for m in moments) + " |",
             "| --- |" + " --- |" * len(moments)]
    short = {"landed: our route": "our route", "landed: the plan": "finished"}
    for f in faults:
        row = []
        for m in moments:
            c = by.get((f, m))
            if c is None:
                row.append("-")
                continue
            end = short.get(c["ended"], c["ended"].replace("landed: ", ""))
            flag = "" if c["clearance_m"] >= result["margin_m"] else " **BELOW**"
            row.append(f"{c['clearance_m']:.1f} m{flag}, {end}")
        lines.append(f"| {f} | " + " | ".join(row) + " |")
    lines += ["", "| cell | summary.json status | names the fault | recording |", "| --- | --- | --- | --- |"]
    for c in cells:
        lines.append(f"| {c['fault']} @ {c['moment']} | {c['status']} | {'yes' if c['report_names_fault'] else 'no'} "
                     f"| {c['recording']} |")
    lines += payload_table(cells)
    descent = result.get("descent_in_place")
    if descent:  # every moment of the clean flight, not the five the cells sample
        lines += ["", f"A descent in place (PX4's landing when the position is lost) from every {DESCENT_EVERY:g} s of "
                  "the clean flight:", "",
                  "| phase | s | descent within the margin | least clearance |", "| --- | --- | --- | --- |"]
        for state, e in descent.items():
            flag = "" if e["min_clearance_m"] >= result["margin_m"] else " **BELOW**"
            least = (f"{e['min_clearance_m']:.2f} m ({e['nearest']}, {e['at_s']:.0f} s)" if e["nearest"]
                     else f">= {DESCENT_RANGE:g} m")
            lines.append(f"| {state} | {e['seconds']:.0f} | {e['within_margin_s']:.1f} s | {least}{flag} |")
    return "\n".join(lines) + "\n"


def plot(result: dict[str, Any], path: Path) -> None:
    """Cells coloured by clearance (red below the margin), the end written in each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = result["cells"]
    moments = [m for m in MOMENTS if any(c["moment"] == m for c in cells)]
    faults = [f for f in FAULTS if any(c["fault"] == f for c in cells)]
    grid = np.full((len(faults), len(moments)), np.nan)
    for c in cells:
        grid[faults.index(c["fault"]), moments.index(c["moment"])] = c["clearance_m"]
    fig, ax = plt.subplots(figsize=(1.9 * len(moments) + 2.5, 0.6 * len(faults) + 1.5))
    margin = result["margin_m"]
    im = ax.imshow(grid, cmap="RdYlGn", vmin=0.0, vmax=max(2 * margin, float(np.nanmax(grid))), aspect="auto")
    for c in cells:
        i, j = faults.index(c["fault"]), moments.index(c["moment"])
        end = c["ended"].replace("landed: ", "")
        ax.text(j, i, f"{c['clearance_m']:.1f} m\n{end}", ha="center", va="center", fontsize=7,
                color="black" if c["clearance_m"] >= margin else "white")
    ax.set_xticks(range(len(moments)), moments)
    ax.set_yticks(range(len(faults)), faults)
    ax.set_title(f"minimum clearance to the true tower and conductors (margin {margin:g} m)")
    fig.colorbar(im, ax=ax, label="m")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="insulator-rs eval faults", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))


def add_arguments(p: argparse.ArgumentParser) -> None:
    from insulator_rs.report import parse_out_folder

    p.add_argument("--out", type=parse_out_folder, required=True, help="folder for the table, JSON, plot and flights")
    p.add_argument("--scene", choices=tuple(SCENES), default="small",
                   help="small: the 12 m cut of tower B (default, 125 s flights); tower_b: the shipped tower B "
                        "(11-minute flights: each cell costs minutes)")
    p.add_argument("--faults", default=",".join(FAULTS), help=f"comma-separated subset of: {', '.join(FAULTS)}")
    p.add_argument("--moments", default=",".join(MOMENTS), help=f"comma-separated subset of: {', '.join(MOMENTS)}")


def run(args: argparse.Namespace) -> int:
    faults = [f.strip() for f in args.faults.split(",") if f.strip()]
    moments = [m.strip() for m in args.moments.split(",") if m.strip()]
    try:
        result = run_matrix(args.out, faults, moments, scene_name=args.scene)
    except ValueError as exc:
        print(f"insulator-rs eval faults: error: {exc}", file=sys.stderr)
        return 2
    print(markdown(result))
    print(f"{len(result['cells'])} cells, {result['below_margin']} below the {result['margin_m']:g} m margin, "
          f"{result['not_landed']} not landed; wall {result['wall_s']:.0f} s")
    return 0 if result["below_margin"] == 0 and result["not_landed"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
