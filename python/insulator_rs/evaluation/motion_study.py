"""``insulator-rs eval motion``: localization error with motion distortion, with and without deskew.

The localization study's events (:mod:`.localization_study`: tower, standoff, stand-in boxes,
a Mid-360 frame cast along the moving trajectory, three detection events accumulated) are
flown faster and turning, so each 100 ms LiDAR frame is smeared by the motion. Every event
is localized twice from the same frames: as measured (each frame used with the pose at its
image time, what the study and the flight did before deskew), and deskewed with
``ir.deskew_points_in_boxes`` against the odometry pose stream (20 Hz, with the study's
odometry noise) to the image time. Reported: the centre error (median, mean) per speed,
yaw rate and pitch rate (the body tilting, as a multirotor does when it starts to brake or a
gust hits it: its attitude swings 17 degrees in a few tenths of a second), for each.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from insulator_rs.evaluation.localization_study import TOWERS, StudyConfig, write_study
from insulator_rs.evaluation.study_scenes import (
    POSE_RATE_HZ,
    StudyRig,
    event_poses,
    localization_errors,
    noisy_pose,
)
from insulator_rs.perception.localization_method import LocalizationMethod
from insulator_rs.perception.pipeline import EVENTS_PER_LOCALIZATION

if TYPE_CHECKING:
    from insulator_rs.sim.detector_standin import DetectorStandin
    from insulator_rs.sim.towers import InsulatorTruth

# A detection event must hold at least this many culled points to count in this study's own
# accumulation; the pipeline's own gate is MIN_POINTS_PER_BOX.
MIN_POINTS_PER_DETECTION = 1
DEFAULT_SPEEDS = (1.0, 3.0, 6.0)  # m/s along the line
DEFAULT_YAW_RATES = (0.0, 30.0)  # deg/s
DEFAULT_PITCH_RATES = (0.0, 30.0)  # deg/s (the command line's; the function's default is 0 only)


@dataclass(frozen=True)
class MotionResult:
    speed: float
    yaw_rate_deg: float
    event: int
    error_raw: float
    error_deskewed: float
    pitch_rate_deg: float = 0.0


def _turning(trajectory: Callable[[float], np.ndarray], t_mid: float, yaw_rate: float,
             pitch_rate: float = 0.0) -> Callable[[float], np.ndarray]:
    """The trajectory with the body also yawing at ``yaw_rate`` rad/s about its own z and
    pitching at ``pitch_rate`` rad/s about its own y (level at ``t_mid``)."""
    def T(t: float) -> np.ndarray:
        a = yaw_rate * (t - t_mid)
        p = pitch_rate * (t - t_mid)
        R = np.eye(4)
        R[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
        P = np.eye(4)
        P[:3, :3] = [[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]]
        return trajectory(t) @ R @ P
    return T


def _event(rig: StudyRig, target: InsulatorTruth, trajectory: Callable[[float], np.ndarray],
           times: Sequence[float], detector: DetectorStandin, rng: np.random.Generator, cfg: StudyConfig
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(raw points in B, deskewed points in B, odometry T_w_b) of the target's 3 detection events."""
    import insulator_rs as ir

    raw, desk = [], []
    for t in times:
        T_true = trajectory(t)
        mine = rig.detected_target(T_true, target.instance_id, detector)
        if mine is None:
            continue
        frame = rig.lidar.scan(rig.mesh, trajectory, t - rig.lidar.frame_period, seed=int(rng.integers(2**31)))
        knots = t - np.arange(4, -1, -1) / POSE_RATE_HZ  # the last knot exactly at the image time
        odom = np.stack([noisy_pose(trajectory(k), rng, cfg) for k in knots])
        T_w_b = odom[-1]  # the pose at the image time, as the pipeline has it
        idx = ir.points_in_boxes(frame.points_l, rig.T_c_l, rig.camera_model, mine[:1, :4])[0]
        deskewed, didx = ir.deskew_points_in_boxes(frame.points_l, np.clip(frame.timestamps, knots[0], knots[-1]),
                                                   knots, odom, t, rig.T_b_l, rig.T_c_l, rig.camera_model,
                                                   mine[:1, :4])
        if len(idx) < MIN_POINTS_PER_DETECTION or len(didx[0]) < MIN_POINTS_PER_DETECTION:
            continue
        raw.append((frame.points_l[idx], T_w_b))
        desk.append((deskewed[didx[0]], T_w_b))
        if len(raw) == EVENTS_PER_LOCALIZATION:
            break
    if len(raw) < EVENTS_PER_LOCALIZATION:
        return None
    T_last = raw[-1][1]
    T_b_w = np.linalg.inv(T_last)

    def in_b(parts: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        out = []
        for pts, T_w_b in parts:
            T = T_b_w @ T_w_b @ rig.T_b_l
            out.append(np.asarray(pts, dtype=np.float64) @ T[:3, :3].T + T[:3, 3])
        return np.vstack(out)

    return in_b(raw), in_b(desk), T_last


def run_motion_study(events: int, speeds: Sequence[float], yaw_rates_deg: Sequence[float], *, tower: str = "A",
                     standoff: float = 8.0, method: LocalizationMethod = LocalizationMethod.DBSCAN_RANSAC, seed: int = 0,
                     pitch_rates_deg: Sequence[float] = (0.0,)) -> list[MotionResult]:
    import insulator_rs as ir
    from insulator_rs.sim.detector_standin import DetectorStandin

    results = []
    for speed, yaw_deg, pitch_deg in ((s, y, p) for s in speeds for y in yaw_rates_deg for p in pitch_rates_deg):
        cfg = replace(StudyConfig(), speed=speed, seed=seed)
        rig = StudyRig(TOWERS[tower], cfg, seed)
        rng = np.random.default_rng(seed * 7919 + int(speed * 100) + int(yaw_deg) + 31 * int(pitch_deg))
        detector = DetectorStandin(jitter=cfg.box_jitter, seed=seed)
        done = attempts = 0
        while done < events and attempts < 20 * events + 20:
            attempts += 1
            target = rig.tower.insulators[int(rng.integers(len(rig.tower.insulators)))]
            trajectory, times = event_poses(rig.tower, target, standoff, rng, cfg)
            trajectory = _turning(trajectory, times[0], math.radians(yaw_deg), math.radians(pitch_deg))
            got = _event(rig, target, trajectory, times, detector, rng, cfg)
            if got is None:
                continue
            raw_b, desk_b, T_w_b = got
            errs = []
            for pts in (raw_b, desk_b):
                try:
                    est = ir.localize(pts, method=method, seed=done)
                except ir.LocalizationError:
                    errs.append(math.nan)
                    continue
                c = T_w_b[:3, :3] @ np.asarray(est.center) + T_w_b[:3, 3]
                d = T_w_b[:3, :3] @ np.asarray(est.direction)
                errs.append(localization_errors(c, d, target)[0])
            results.append(MotionResult(speed, yaw_deg, done, errs[0], errs[1], pitch_deg))
            done += 1
    return results


def format_table(results: Sequence[MotionResult]) -> str:
    lines = ["speed m/s | yaw deg/s | pitch deg/s | events | raw median / mean m | deskewed median / mean m"]
    keys = sorted({(r.speed, r.yaw_rate_deg, r.pitch_rate_deg) for r in results})
    for sp, yw, pt in keys:
        rows = [r for r in results if (r.speed, r.yaw_rate_deg, r.pitch_rate_deg) == (sp, yw, pt)]
        raw = np.array([r.error_raw for r in rows])
        desk = np.array([r.error_deskewed for r in rows])
        lines.append(f"{sp:9.1f} | {yw:9.0f} | {pt:11.0f} | {len(rows):6d} | {np.nanmedian(raw):.3f} / {np.nanmean(raw):.3f}"
                     f"       | {np.nanmedian(desk):.3f} / {np.nanmean(desk):.3f}")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--events", type=int, default=30, help="events per (speed, yaw rate) cell")
    parser.add_argument("--speeds", nargs="+", type=float, default=list(DEFAULT_SPEEDS), help="m/s")
    parser.add_argument("--yaw-rates", nargs="+", type=float, default=list(DEFAULT_YAW_RATES), help="deg/s")
    parser.add_argument("--pitch-rates", nargs="+", type=float, default=list(DEFAULT_PITCH_RATES),
                        help="deg/s: the body tilting during the frame (braking, gusts)")
    parser.add_argument("--tower", choices=("A", "B"), default="A", help="tower to fly past")
    parser.add_argument("--standoff", type=float, default=8.0, help="distance w from the line plane, m")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the study (integer)")
    parser.add_argument("--out", type=Path, default=Path("results/motion"), help="folder for the table and plot")


def run(args: argparse.Namespace) -> int:
    if args.events < 1 or any(not (math.isfinite(s) and s >= 0) for s in args.speeds):
        print("insulator-rs eval motion: error: --events must be >= 1 and --speeds >= 0")
        return 2
    results = run_motion_study(args.events, args.speeds, args.yaw_rates, tower=args.tower, standoff=args.standoff,
                               seed=args.seed, pitch_rates_deg=args.pitch_rates)
    return write_study(args.out, "motion_study", results, format_table(results))
