"""The localization study on a real airframe: wind, braking, and what the level assumption costs.

The localization study (``localization_study.py``) flies a level body along the line. Here
the UAV is the simulated multirotor (``sim/kinematics.py``): it tilts along its thrust and
leans into the wind. One event:

1. as in the localization study, the target insulator, its side, the standoff and the yaw
   are drawn; the wind (``wind`` m/s, Dryden turbulence, from a direction drawn per event)
   is set, and the airframe flies along the line at :data:`BRAKE_FROM_SPEED` (or the study's
   speed when it does not brake) for :data:`LEAD_IN_S`, settled in the wind;
2. it then brakes at ``braking`` m/s^2 (0: cruises on) and the images are taken from the
   start of the braking, so the first detection events see the vehicle tilted atan(a/g);
3. the LiDAR and the camera render from the airframe's TRUE pose (the simulator's track);
   the pipeline gets the vehicle's reported odometry at 20 Hz twice, as two pose streams:
   ``full`` (the attitude the vehicle reports) and ``level`` (the same poses with roll and
   pitch removed: the body taken as level, as the vehicle port did before it reported the
   attitude). Both see the same scans and boxes, so the difference is the attitude alone.

``insulator-rs eval airframe --winds 0 5 10 --braking 3`` runs these cells.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from insulator_rs import bounds
from insulator_rs.evaluation.localization_study import TOWERS, StudyConfig, cell_inputs, draw_events, write_study
from insulator_rs.evaluation.study_scenes import (MAX_IMAGES_PER_EVENT, POSE_RATE_HZ, StudyRig, localization_errors,
                                                  localize_event)
from insulator_rs.perception.localization_method import LocalizationMethod
from insulator_rs.report.folder import parse_out_folder
from insulator_rs.poses import interpolate_poses, level_pose, tilt_of
from insulator_rs.ports.sensors import PoseStamped

# m/s: the airframe brakes from the paper's planning speed (3 m/s) to a stop
BRAKE_FROM_SPEED = 3.0
# s of flight before the first image: the attitude (0.15 s lag) and the gusts settled
LEAD_IN_S = 2.0
STREAMS = ("full", "level")


@dataclass(frozen=True)
class AirframeResult:
    """One event with one method and one pose stream (errors in m; NaN when it failed).
    ``tilt_deg``: the airframe's true tilt at the first image."""

    tower: str
    standoff: float
    wind: float
    braking: float
    event: int
    method: str
    attitude: str
    ok: bool
    error: float
    outcome: str
    tilt_deg: float


@dataclass(frozen=True)
class AirframeCell:
    """Statistics of one (wind, braking, method, attitude) cell over its successful events."""

    tower: str
    standoff: float
    wind: float
    braking: float
    method: str
    attitude: str
    n: int
    failures: int
    mean: float
    std: float
    tilt_mean_deg: float


def flown_event(rig: StudyRig, target_center: np.ndarray, side: float, standoff: float, rng: np.random.Generator,
                cfg: StudyConfig, wind: float, braking: float
                ) -> tuple[Callable[[float], np.ndarray], list[float], list[PoseStamped]]:
    """Fly one event (module docstring): (true trajectory t -> T_w_b, image times, the vehicle's
    reported poses at POSE_RATE_HZ over the whole event)."""
    from insulator_rs.sim.kinematics import KinematicVehicle, OdometryNoise, Setpoint, SimClock
    from insulator_rs.sim.wind import WindSpec

    tower = rig.tower
    lateral = np.asarray(tower.spec.lateral_direction)
    along = np.asarray(tower.spec.line_direction)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    speed = BRAKE_FROM_SPEED if braking > 0 else cfg.speed
    brake_time = speed / braking if braking > 0 else math.inf
    period = max(cfg.event_interval, 0.1)
    # where the first image is taken: the random offset along the line, as the level study's
    first = (target_center + side * standoff * lateral + rng.uniform(-cfg.along_spread, cfg.along_spread) * along
             + np.array([0.0, 0.0, rng.uniform(*cfg.height_range)]))
    start = first - sign * along * speed * LEAD_IN_S
    yaw = (math.atan2(-side * lateral[1], -side * lateral[0])
           + math.radians(cfg.yaw_jitter_deg) * rng.uniform(-1.0, 1.0))
    t0 = float(rng.uniform(0.0, 1000.0))
    vehicle = KinematicVehicle(
        start_position=start, start_yaw=yaw, ground_z=start[2] - 50.0, clock=SimClock(t0),
        noise=OdometryNoise(position=cfg.odom_position_noise, yaw=math.radians(cfg.odom_yaw_noise_deg)),
        seed=int(rng.integers(2**31)),
        wind=WindSpec(speed=wind, from_deg=float(rng.uniform(0.0, 360.0)), seed=int(rng.integers(2**31))))
    vehicle.model.velocity = sign * along * speed
    t_brake = t0 + LEAD_IN_S
    times = [t_brake + k * period for k in range(MAX_IMAGES_PER_EVENT)]
    t_end = times[-1] + 2 * rig.lidar.frame_period

    def setpoint(t: float) -> Setpoint:
        v = speed - braking * max(0.0, t - t_brake) if math.isfinite(brake_time) else speed
        return Setpoint(position=np.array([math.nan, math.nan, start[2]]), velocity=sign * along * max(v, 0.0),
                        yaw=yaw)

    vehicle.command_setpoint(setpoint(t0))
    vehicle.arm()
    vehicle.set_mode("OFFBOARD")
    dt = 1.0 / POSE_RATE_HZ
    poses: list[PoseStamped] = []
    track: list[tuple[float, np.ndarray]] = [(t0, vehicle.true_T_w_b())]
    while vehicle.clock.now < t_end:
        vehicle.command_setpoint(setpoint(vehicle.clock.now))
        st = vehicle.advance(dt)
        track.extend(s for s in list(vehicle.true_track)[-5:] if s[0] > track[-1][0])
        poses.append(PoseStamped(st.time, st.T_w_b))
    knots_t = np.array([t for t, _ in track])
    knots_T = np.stack([T for _, T in track])

    def trajectory(t: float) -> np.ndarray:
        return interpolate_poses(knots_t, knots_T, np.array([t]))[0]

    return trajectory, times, poses


def run_airframe_cell(rig: StudyRig, tower_key: str, standoff: float, cfg: StudyConfig, wind: float,
                      braking: float) -> list[AirframeResult]:
    """``cfg.events`` flown events in ``wind`` m/s braking at ``braking`` m/s^2; one result per
    event, method and pose stream (full attitude, level)."""
    seed = cfg.seed * 1000 + int(round(standoff * 10)) + int(round(wind * 7)) + int(round(braking * 13)) + 77
    rng, detector, length = cell_inputs(tower_key, cfg, seed)
    insulators = rig.tower.insulators
    results: list[AirframeResult] = []

    def attempt(event: int) -> bool:
        target = insulators[int(rng.integers(len(insulators)))]
        trajectory, times, poses = flown_event(rig, target.center, target.side, standoff, rng, cfg, wind, braking)
        stamps = np.array([p.time for p in poses])

        def odometry(t0: float, t1: float) -> dict[str, list[PoseStamped]]:
            chosen = [poses[k] for k in np.flatnonzero((stamps >= t0 - 1e-9) & (stamps <= t1 + 1e-9))]
            return {"full": chosen, "level": [PoseStamped(p.time, level_pose(p.T_w_b)) for p in chosen]}

        got = localize_event(rig, target, trajectory, times, detector, rng, cfg, length, odometry)
        if got is None:
            return False
        tilt = math.degrees(tilt_of(trajectory(times[0])))
        for method in cfg.methods:
            for stream in STREAMS:
                # a stream whose pipeline had not attempted yet when the other did (its culled
                # points differ): no localization at that image, a failure
                loc, outcome, _, _ = got.get((method, stream), (None, "not attempted", 0, math.nan))
                err = localization_errors(loc.center, loc.axis, target)[0] if loc is not None else math.nan
                results.append(AirframeResult(tower_key, standoff, wind, braking, event, method, stream,
                                              loc is not None, err, outcome, tilt))
        return True

    draw_events(cfg.events, f"tower {tower_key}, w = {standoff} m, wind {wind:g} m/s", attempt)
    return results


def summarize_airframe(results: Sequence[AirframeResult]) -> list[AirframeCell]:
    """One :class:`AirframeCell` per (tower, standoff, wind, braking, method, attitude), in order."""
    keys = list(dict.fromkeys((r.tower, r.standoff, r.wind, r.braking, r.method, r.attitude) for r in results))
    out = []
    for key in keys:
        rows = [r for r in results if (r.tower, r.standoff, r.wind, r.braking, r.method, r.attitude) == key]
        errs = np.array([r.error for r in rows if r.ok])
        out.append(AirframeCell(*key, n=len(errs), failures=len(rows) - len(errs),
                                mean=float(errs.mean()) if len(errs) else math.nan,
                                std=float(errs.std(ddof=1)) if len(errs) > 1 else 0.0,
                                tilt_mean_deg=float(np.mean([r.tilt_deg for r in rows]))))
    return out


def format_airframe_table(cells: Sequence[AirframeCell]) -> str:
    """Full attitude beside the level assumption, one row per (wind, braking, method)."""
    lines = ["Airframe cells: centre error [m], mean ± std (failures/events); tilt at the first image",
             f"{'tower':<6}{'w [m]':<7}{'wind':<7}{'brake':<7}{'method':<16}{'tilt':<8}"
             f"{'full attitude':<24}{'level (yaw only)':<24}"]
    for c in cells:
        if c.attitude != "full":
            continue
        lvl = next((x for x in cells if x.attitude == "level" and (x.tower, x.standoff, x.wind, x.braking, x.method)
                    == (c.tower, c.standoff, c.wind, c.braking, c.method)), None)

        def cell(x: AirframeCell | None) -> str:
            return "" if x is None else f"{x.mean:.3f} ± {x.std:.3f} ({x.failures}/{x.n + x.failures})"

        lines.append(f"{c.tower:<6}{c.standoff:<7g}{c.wind:<7g}{c.braking:<7g}{c.method:<16}"
                     f"{c.tilt_mean_deg:<8.1f}{cell(c):<24}{cell(lvl):<24}")
    return "\n".join(lines)


def run_airframe_study(cfg: StudyConfig, winds: Sequence[float], braking: float) -> list[AirframeCell]:
    """The airframe cells of every tower and standoff of ``cfg``, each wind, braking at ``braking``."""
    results: list[AirframeResult] = []
    for tower_key in cfg.towers:
        rig = StudyRig(TOWERS[tower_key], cfg, seed=cfg.seed)
        for w in cfg.standoffs[tower_key]:
            for wind in winds:
                results.extend(run_airframe_cell(rig, tower_key, w, cfg, wind, braking))
    return summarize_airframe(results)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``insulator-rs eval airframe``."""
    parser.add_argument("--towers", nargs="+", choices=sorted(TOWERS), default=["A"], help="towers to fly")
    parser.add_argument("--standoffs", nargs="+", type=float, default=[8.0], help="m (default 8)")
    parser.add_argument("--events", type=int, default=8, help="events per cell (default 8)")
    parser.add_argument("--methods", nargs="+", type=LocalizationMethod, choices=list(LocalizationMethod),
                        default=[LocalizationMethod.BOUNDED, LocalizationMethod.DBSCAN_RANSAC],
                        help="localization methods to compare")
    parser.add_argument("--winds", nargs="+", type=bounds.option("--wind"), default=[0.0, 5.0, 10.0],
                        help="mean winds, m/s (default 0 5 10)")
    parser.add_argument("--braking", type=bounds.option("--a-max"), default=3.0,
                        help="m/s^2 (default 3: the paper's a_max)")
    parser.add_argument("--seed", type=bounds.option("--seed"), default=0,
                        help="random seed of the study (integer, 0 to 2^32-1)")
    parser.add_argument("--out", type=parse_out_folder, default=Path("results/airframe"),
                        help="folder for the study's table and plot (created)")


def run(args: argparse.Namespace) -> int:
    """Entry point of ``insulator-rs eval airframe``: prints the table, writes airframe.csv/.txt."""
    if args.events < 1 or any(not (math.isfinite(w) and w > 0) for w in args.standoffs):
        print("insulator-rs eval airframe: error: --events must be >= 1 and --standoffs > 0")
        return 2
    cfg = StudyConfig(towers=tuple(args.towers), standoffs={k: tuple(args.standoffs) for k in TOWERS},
                      events=args.events, methods=tuple(args.methods), seed=args.seed)
    cells = run_airframe_study(cfg, args.winds, args.braking)
    return write_study(args.out, "airframe", cells, format_airframe_table(cells))
