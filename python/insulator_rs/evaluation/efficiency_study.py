"""``insulator-rs eval efficiency``: single-flight vs two-flight inspection time (the paper's
efficiency figure), plus a cheapest-insertion buffering strategy.

Set-up (stated, so the numbers can be reproduced and judged):

* Towers A and B of the built-in simulator (``sim.towers``), planned from the
  example mission files (``missions/tower_*.toml``) with the study's limits:
  v_max 3 m/s and a_max 12 m/s^2 on every axis, as in the paper.
* N inspection waypoints are spread over the insulators in ground-truth order,
  round-robin (insulator i gets N // n + (i < N mod n) viewpoints; with N < n
  only the first N insulators are inspected). The viewpoints are those of
  :func:`~insulator_rs.planning.waypoints.inspection_waypoints`, framed for the
  simulator rig's inspection camera (zoom on a gimbal) exactly as the flight frames them,
  identical for both strategies.
* Visibility model: every ``SENSE_PERIOD`` s the vehicle (camera level along
  the body x axis, yaw towards the tower while exploring, towards the
  insulator while inspecting) sees an insulator when at least
  ``MIN_VISIBLE_POINTS`` of ``AXIS_SAMPLES`` points along its axis are within
  ``DETECTION_RANGE`` of the vehicle, project into the simulated camera's image
  (``ir.project_points``, the simulator's default camera) and are not occluded:
  a ray cast through the simulator's scene (tower lattice, conductors, other
  insulators) first hits that insulator. Whenever one is seen, the flight's own
  :class:`~insulator_rs.perception.pipeline.PerceptionPipeline` gets the detection frame
  (the seen insulators' boxes: their projected outlines) and the simulated Mid-360 scans of
  that instant (the scan ending then and the next, cast along the vehicle's motion, as the
  flight pairs them) and localizes them, accumulating three detection events, with the
  DBSCAN+RANSAC default and its plausibility gates; the registry confirms an insulator as
  in flight. The viewpoints stay those of the ground-truth insulators, so both strategies
  visit the same waypoints: what the pipeline decides is when (and whether) an insulator is
  found, i.e. where the detours happen.
* All times are point-mass-model times with optimised waypoint velocities.
  Single flight: take-off, exploration with detours, landing at the take-off
  point. Two flights: the scan flight (the same exploration path, no stops)
  plus the exact optimal tour from the take-off point through the N waypoints
  with over-the-top crossings (:mod:`insulator_rs.evaluation.two_flight`).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

import insulator_rs as ir
from insulator_rs.mission.config import Mission, load_mission
from insulator_rs.perception.stack import rig_pipeline
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.planning.pmm import rest_to_rest_times
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry
from insulator_rs.evaluation.single_flight import fly_single_flight
from insulator_rs.mission.state_machine import InspectionStateMachine, Policy
from insulator_rs.evaluation.two_flight import two_flight
from insulator_rs.planning.waypoints import InspectionWaypoint, inspection_waypoints
from insulator_rs.poses import pose_from_yaw
from insulator_rs.rig import simulator_rig
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped
from insulator_rs.sim.lidar import Mid360
from insulator_rs.report.folder import parse_out_folder
from insulator_rs.sim.towers import Tower, load_tower

V_MAX = 3.0  # m/s, every axis (paper)
A_MAX = 12.0  # m/s^2, every axis (paper)
N_VALUES = tuple(range(4, 25))
SENSE_PERIOD = 0.2  # s, detector rate of 5 Hz
DETECTION_RANGE = 20.0  # m, where the Mid-360 still puts enough points on an insulator
AXIS_SAMPLES = 5
MIN_VISIBLE_POINTS = 2
POSE_RATE_HZ = 20.0  # the flight loop feeds the pose history every control tick
MISSIONS_DIR = Path(__file__).resolve().parents[1] / "missions"
TOWERS = ("tower_a", "tower_b")
POLICIES = ("immediate", "insertion")


class VisibilityModel:
    """Which ground-truth insulators the sensors see from a pose (see the module docstring)."""

    def __init__(self, tower: Tower, *, detection_range: float = DETECTION_RANGE) -> None:
        self.tower = tower
        rig = simulator_rig()
        self.cam = rig.camera
        self.T_b_c = rig.T_b_c
        self.range = detection_range
        self.scene = tower.mesh.raycaster
        offsets = np.linspace(-0.4, 0.4, AXIS_SAMPLES)
        self.points = np.array([[ins.center + f * ins.length * ins.axis for f in offsets]
                                for ins in tower.insulators])  # (n, S, 3)
        self.ids = np.array([ins.instance_id for ins in tower.insulators])

    def visible(self, position: np.ndarray, yaw: float) -> np.ndarray:
        """(n,) bool: insulators seen from a level body at ``position`` (W) with heading ``yaw``."""
        T_w_b = np.eye(4)
        c, s = math.cos(yaw), math.sin(yaw)
        T_w_b[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        T_w_b[:3, 3] = position
        T_c_w = np.linalg.inv(T_w_b @ self.T_b_c)
        pts = self.points.reshape(-1, 3)
        _, in_image = ir.project_points(pts, T_c_w, self.cam)
        diff = pts - position
        dist = np.linalg.norm(diff, axis=1)
        ok = in_image & (dist <= self.range)
        if np.any(ok):
            hits = self.scene.cast(np.repeat(position[None], int(ok.sum()), axis=0),
                                   diff[ok] / dist[ok, None], float(self.range) + 1.0)
            own = np.repeat(self.ids, AXIS_SAMPLES)[ok]
            seen = np.zeros(len(pts), dtype=bool)
            seen[np.flatnonzero(ok)] = np.asarray(hits.instance_id) == own
            ok = seen
        return ok.reshape(len(self.ids), AXIS_SAMPLES).sum(axis=1) >= MIN_VISIBLE_POINTS



class PipelineSensing:
    """The single flight's sensing: the visibility model says which insulators the camera sees;
    the flight's perception pipeline localizes them from simulated Mid-360 scans (see the
    module docstring). ``sense`` is the ``Sense`` callback of ``fly_single_flight``."""

    def __init__(self, tower: Tower, insulator_length: float, *, seed: int = 0) -> None:
        rig = simulator_rig()
        self.tower = tower
        self.visibility = VisibilityModel(tower)
        self.lidar = Mid360(rig.T_b_l)
        self.camera, self.T_b_c = rig.camera, rig.T_b_c
        self.pipeline = rig_pipeline(rig, insulator_length=insulator_length)
        self.image = np.broadcast_to(np.zeros(3, np.uint8), (rig.camera.height, rig.camera.width, 3))
        mesh = tower.mesh
        self.vertices = [mesh.vertices[np.unique(mesh.triangles[mesh.instance_ids == i.instance_id])]
                         for i in tower.insulators]
        self._last: tuple[float, np.ndarray] | None = None
        self._seed = seed
        self.scans = 0

    def _boxes(self, seen: np.ndarray, T_w_b: np.ndarray) -> np.ndarray:
        """The projected outline (x1, y1, x2, y2) of each seen insulator, clipped to the image."""
        T_c_w = np.linalg.inv(T_w_b @ self.T_b_c)
        size = np.array([self.camera.width, self.camera.height], dtype=np.float64)
        boxes = []
        for i in np.flatnonzero(seen):
            uv, ok = ir.project_points(self.vertices[i], T_c_w, self.camera)
            if not np.any(ok):
                continue
            lo, hi = np.clip(uv[ok].min(axis=0), 0, size), np.clip(uv[ok].max(axis=0), 0, size)
            if np.all(hi - lo >= 2):
                boxes.append([lo[0], lo[1], hi[0], hi[1]])
        return np.array(boxes, dtype=np.float64).reshape(-1, 4)

    def sense(self, position: np.ndarray, yaw: float, time: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Localizations the pipeline makes at this poll."""
        if self._last is None or time <= self._last[0]:
            velocity = np.zeros(3)
        else:
            velocity = (position - self._last[1]) / (time - self._last[0])
        self._last = (time, position.copy())
        seen = self.visibility.visible(position, yaw)
        if not np.any(seen):
            return []
        boxes = self._boxes(seen, pose_from_yaw(position, yaw))
        if len(boxes) == 0:
            return []

        def trajectory(t: float) -> np.ndarray:  # the vehicle's motion around this instant
            return pose_from_yaw(position + velocity * (t - time), yaw)

        period = self.lidar.frame_period
        for t in np.arange(time - period, time + period + 1e-9, 1.0 / POSE_RATE_HZ):
            self.pipeline.add_pose(PoseStamped(float(t), trajectory(float(t))))
        for t_end in (time, time + period):
            self._seed += 1
            frame = self.lidar.scan(self.tower.mesh, trajectory, t_end - period, seed=self._seed)
            self.pipeline.add_scan(LidarScan(frame.points_l, frame.timestamps, self.lidar.T_b_l))
            self.scans += 1
        out = self.pipeline.process(CameraFrame(time, self.image, self.camera, self.T_b_c), boxes)
        return [(loc.center, loc.axis) for loc in out]


def waypoint_counts(n_insulators: int, n_waypoints: int) -> list[int]:
    """Round-robin share of ``n_waypoints`` over ``n_insulators`` (ground-truth order)."""
    return [n_waypoints // n_insulators + (1 if i < n_waypoints % n_insulators else 0)
            for i in range(n_insulators)]


@dataclass(frozen=True)
class StudyRow:
    tower: str
    n: int
    t_scan: float
    t_tsp: float
    t_fusion: float
    t_fusion_insertion: float
    inspected: int
    inspected_insertion: int
    safe: bool

    @property
    def t_two_flight(self) -> float:
        return self.t_scan + self.t_tsp

    def saving(self, t: float) -> float:
        """Percent of the two-flight time saved by a single flight of time ``t`` (negative: extra)."""
        return 100.0 * (self.t_two_flight - t) / self.t_two_flight


class TowerStudy:
    """One tower's planning geometry, ground truth and viewpoint factory."""

    def __init__(self, name: str) -> None:
        mission = load_mission(MISSIONS_DIR / f"{name}.toml")
        limits = replace(mission.vehicle, v_max_horizontal=V_MAX, a_max_horizontal=A_MAX,
                         v_max_vertical=V_MAX, a_max_vertical=A_MAX)
        self.mission: Mission = replace(mission, vehicle=limits)
        self.geom = MissionGeometry.from_mission(self.mission)
        self.tower = load_tower(name)
        self.name = name
        self.v_max = self.mission.vehicle.v_max()
        self.a_max = self.mission.vehicle.a_max()
        rig = simulator_rig()
        # The shots are framed as the flight frames them (``FlightLoop``): by the rig's zoom
        # inspection camera on its gimbal, the detection camera's field of view as the fallback.
        self.camera, self.inspection = rig.camera, rig.inspection
        self.fov = 2 * math.atan((rig.camera.height / 2) / rig.camera.fy)

    def viewpoints(self, gt_index: int, count: int, insulator_id: int) -> list[InspectionWaypoint]:
        if count == 0:
            return []
        ins = self.tower.insulators[gt_index]
        p = self.mission.inspection
        return inspection_waypoints(ins.center, ins.axis, insulator_id=insulator_id, line=self.geom.line,
                                    volumes=self.geom.volumes, count=count,
                                    inspection_distance=p.inspection_distance,
                                    insulator_length=ins.length, fov=self.fov, camera=self.camera,
                                    inspection=self.inspection)

    def gt_index(self, center: np.ndarray) -> int:
        return int(np.argmin([np.linalg.norm(i.center - center) for i in self.tower.insulators]))

    def single_flight(self, counts: list[int], policy: str) -> tuple[float, int, bool]:
        """(flight time s, insulators inspected, trajectory safe) of one online single flight."""
        reg = InsulatorRegistry(self.geom.line, self.mission.inspection.registry_gate,
                                self.mission.inspection.confirmations)

        def make(ins: Insulator) -> list[InspectionWaypoint]:
            k = self.gt_index(ins.center)
            return self.viewpoints(k, counts[k], ins.id)

        def cost(a: np.ndarray, b: np.ndarray) -> float:
            return float(rest_to_rest_times(a, b, self.v_max, self.a_max))

        sm = InspectionStateMachine(self.geom.path, reg, make, policy=Policy(policy), cost=cost)
        sm.start(0.0)
        sensing = PipelineSensing(self.tower, self.mission.inspection.insulator_length)
        res = fly_single_flight(sm, v_max=self.v_max, a_max=self.a_max, sense=sensing.sense,
                                sense_period=SENSE_PERIOD)
        inspected = sum(1 for ins in reg.insulators if ins.inspected and counts[self.gt_index(ins.center)])
        safe = self.geom.volumes.samples_clear(res.positions,
                                               max_step=float(np.linalg.norm(self.v_max)) * SENSE_PERIOD)
        return res.time, inspected, safe

    def row(self, n: int) -> StudyRow:
        counts = waypoint_counts(len(self.tower.insulators), n)
        wps = [w.position for k, c in enumerate(counts) for w in self.viewpoints(k, c, k + 1)]
        tf = two_flight(self.geom.path_points(), np.array(wps), line=self.geom.line,
                        volumes=self.geom.volumes,
                        clearance=self.mission.inspection.crossing_clearance,
                        v_max=self.v_max, a_max=self.a_max)
        t_imm, ins_imm, safe_imm = self.single_flight(counts, "immediate")
        t_ins, ins_ins, safe_ins = self.single_flight(counts, "insertion")
        safe = safe_imm and safe_ins and self.geom.volumes.polyline_clear(tf.tour_route)
        return StudyRow(self.name, n, tf.t_scan, tf.t_tsp, t_imm, t_ins, ins_imm, ins_ins, safe)


CSV_FIELDS = ("tower", "N", "T_scan_s", "T_tsp_s", "T_two_flight_s", "T_fusion_s",
              "T_fusion_insertion_s", "saving_pct", "saving_insertion_pct", "insulators_to_inspect",
              "inspected", "inspected_insertion", "safe")


def run_study(towers: tuple[str, ...], n_values: tuple[int, ...], *, progress: bool = True) -> list[StudyRow]:
    rows = []
    for name in towers:
        study = TowerStudy(name)
        for n in n_values:
            t0 = time.perf_counter()
            row = study.row(n)
            rows.append(row)
            if progress:
                print(f"  {name} N={n:2d}: fusion {row.t_fusion:6.1f} s, insertion "
                      f"{row.t_fusion_insertion:6.1f} s, scan+tsp {row.t_two_flight:6.1f} s "
                      f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
    return rows


def to_insulators(row: StudyRow, n_insulators: int) -> int:
    return sum(1 for c in waypoint_counts(n_insulators, row.n) if c)


def write_csv(rows: list[StudyRow], path: Path, n_insulators: dict[str, int]) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_FIELDS)
        for r in rows:
            w.writerow([r.tower, r.n, f"{r.t_scan:.2f}", f"{r.t_tsp:.2f}", f"{r.t_two_flight:.2f}",
                        f"{r.t_fusion:.2f}", f"{r.t_fusion_insertion:.2f}", f"{r.saving(r.t_fusion):.1f}",
                        f"{r.saving(r.t_fusion_insertion):.1f}", to_insulators(r, n_insulators[r.tower]),
                        r.inspected, r.inspected_insertion, r.safe])


def format_table(rows: list[StudyRow]) -> str:
    head = (f"{'tower':8} {'N':>3} {'T_scan':>7} {'T_tsp':>7} {'scan+tsp':>8} {'T_fusion':>8} "
            f"{'saved%':>7} {'T_insert':>8} {'saved%':>7} {'safe':>5}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r.tower:8} {r.n:3d} {r.t_scan:7.1f} {r.t_tsp:7.1f} {r.t_two_flight:8.1f} "
                     f"{r.t_fusion:8.1f} {r.saving(r.t_fusion):7.1f} {r.t_fusion_insertion:8.1f} "
                     f"{r.saving(r.t_fusion_insertion):7.1f} {str(r.safe):>5}")
    return "\n".join(lines)


def plot(rows: list[StudyRow], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    towers = sorted({r.tower for r in rows})
    fig, axes = plt.subplots(1, len(towers), figsize=(6 * len(towers), 4.2), squeeze=False)
    for ax, name in zip(axes[0], towers):
        rs = [r for r in rows if r.tower == name]
        n = [r.n for r in rs]
        ax.plot(n, [r.t_fusion for r in rs], "o-", label="$T_{fusion}$ (single flight, paper)")
        ax.plot(n, [r.t_fusion_insertion for r in rs], "s-", label="$T_{fusion}$ (cheapest insertion)")
        ax.plot(n, [r.t_tsp for r in rs], "^--", label="$T_{tsp}$")
        ax.plot(n, [r.t_two_flight for r in rs], "v-", label="$T_{scan} + T_{tsp}$")
        ax.set_title(f"{name.replace('_', ' ').title()} (v_max {V_MAX:g} m/s, a_max {A_MAX:g} m/s²)")
        ax.set_xlabel("inspection waypoints N")
        ax.set_ylabel("flight time [s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=parse_out_folder, default=Path("docs/results/efficiency"),
                        help="folder for efficiency.csv and efficiency.png (created)")
    parser.add_argument("--towers", nargs="+", choices=TOWERS, default=list(TOWERS), help="towers to plan for")
    parser.add_argument("--n", type=int, nargs="+", default=list(N_VALUES), metavar="N",
                        help="numbers of inspection waypoints (default 4..24)")


def run(args: argparse.Namespace) -> int:
    if any(n < 1 for n in args.n):
        raise ValueError(f"--n: every N must be >= 1, got {args.n}")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    print(f"efficiency study: towers {', '.join(args.towers)}, N = {min(args.n)}..{max(args.n)}",
          file=sys.stderr)
    rows = run_study(tuple(args.towers), tuple(args.n))
    n_ins = {name: len(load_tower(name).insulators) for name in args.towers}
    print(format_table(rows))
    write_csv(rows, out / "efficiency.csv", n_ins)
    plot(rows, out / "efficiency.png")
    print(f"wrote {out / 'efficiency.csv'} and {out / 'efficiency.png'}")
    return 0
