"""``insulator-rs replay``: re-process recorded flights offline (one, or a fleet on Ray).

``replay FLIGHT`` reads an MCAP file, a rosbag2 folder (sqlite3 or MCAP) or a ROS 1 ``.bag``
and writes the flight's report to ``--out``. ``replay DIR`` with a folder of recordings (or
several FLIGHTs) re-processes each into ``--out/<name>/`` and writes ``fleet_summary.json``;
``--workers N`` runs them in parallel on Ray (a local Ray by default, ``--address`` joins a
running cluster: ``ray start --head`` on one machine, ``ray start --address=HEAD:6379`` on the
others, insulator_rs installed on all). One flight and a fleet run the same function,
:func:`~insulator_rs.replay.batch.replay_one`; the scene named by the recording (or --scene) scores each
report afterwards (``score.json``).

The mission (tower, line, inspection parameters) comes from the recording when insulator_rs
recorded it, else from ``--mission``; ground truth (errors in the report) from the scene the
recording names or ``--scene``. Topic and frame names default to livox_ros_driver2's, a ROS
camera driver's and PX4's (``/livox/lidar``, ``/camera/image_raw/compressed``,
``/fmu/out/vehicle_odometry`` or ``/odom``, ``/tf_static``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from insulator_rs.exceptions import BagError, ConfigError
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.recording.types import Topics
from insulator_rs.replay.batch import DEFAULT_DETECTOR, ReplayOptions, find_flights, replay_one
from insulator_rs.report.jsonfile import write_json

def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("replay", help="re-process recorded flights (MCAP, rosbag2, ROS 1 bag) offline",
                              description="""\
Re-process recorded flights offline through the flight's own perception, and write each
flight's report folder.

FLIGHT is an MCAP file, a rosbag2 folder (sqlite3 or MCAP) or a ROS 1 .bag. A folder of
recordings (or several FLIGHTs) is re-processed into --out/NAME/ each, with fleet_summary.json;
--workers N runs them in parallel on Ray (a local Ray, or a running cluster with --address).
The mission comes from the recording when insulator_rs recorded it, else from --mission; where
the recording (or --scene) names a simulated scene, each report is scored (score.json).
Topic and frame names default to livox_ros_driver2's, a ROS camera driver's and PX4's.""")
    p.add_argument("flights", nargs="+", type=Path, help="recordings, or folders of recordings")
    p.add_argument("--out", type=Path, default=Path("replay_report"), help="report folder (created)")
    p.add_argument("--mission", default=None, help="mission file (default: the one the recording carries)")
    p.add_argument("--rig", default=None,
                   help="rig file to replay with instead of the mission's (its [camera] latency_s, e.g. as "
                        "calibrate time-offset wrote it, is applied to the recorded frame stamps; "
                        "default: the mission's rig)")
    p.add_argument("--scene", default=None,
                   help="scene whose ground truth scores the replay (simulated flights; default: the scene the "
                        "recording names, if any)")
    p.add_argument("--detector", default=DEFAULT_DETECTOR,
                   help=f"shipped model name or ONNX file (default {DEFAULT_DETECTOR})")
    p.add_argument("--method", type=LocalizationMethod, default=DEFAULT_METHOD, choices=list(LocalizationMethod),
                   help="localization method (default %(default)s, as inspect)")
    p.add_argument("--no-deskew", action="store_true", help="do not motion-compensate the LiDAR scans")
    p.add_argument("--detect-period", type=float, default=0.0,
                   help="s between detection events (default 0: every recorded frame)")
    d = Topics()
    for name in ("lidar", "image", "camera_info", "odometry", "tf_static"):
        p.add_argument(f"--{name.replace('_', '-')}-topic", dest=f"{name}_topic", default=getattr(d, name),
                       help=f"default {getattr(d, name)}")
    for name in ("world", "body", "lidar", "camera"):
        p.add_argument(f"--{name}-frame", dest=f"{name}_frame", default=getattr(d, f"{name}_frame"),
                       help=f"tf frame name (default {getattr(d, f'{name}_frame')})")
    p.add_argument("--max-gap", type=float, default=2.0, help="s: a stamp drifting further than this from the recorder's clock is a jump (an error)")
    p.add_argument("--workers", type=int, default=1, help="flights in parallel, on Ray (default 1: no Ray)")
    p.add_argument("--address", default=None, help="Ray cluster address to join (default: a local Ray)")
    p.add_argument("--rerun", action="store_true", help="log the replay to Rerun: OUT/replay.rrd (no viewer)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier insulator_rs report in --out (swapped in when the replay ends)")
    p.set_defaults(func=run)


def _options(args: argparse.Namespace) -> ReplayOptions:
    if not (math.isfinite(args.detect_period) and args.detect_period >= 0):
        raise ValueError(f"--detect-period: must be >= 0, got {args.detect_period}")
    if not (math.isfinite(args.max_gap) and args.max_gap > 0):
        raise ValueError(f"--max-gap: must be > 0, got {args.max_gap}")
    if args.workers < 1:
        raise ValueError(f"--workers: must be >= 1, got {args.workers}")
    topics = Topics(lidar=args.lidar_topic, image=args.image_topic, camera_info=args.camera_info_topic,
                    odometry=args.odometry_topic, tf_static=args.tf_static_topic, world_frame=args.world_frame,
                    body_frame=args.body_frame, lidar_frame=args.lidar_frame, camera_frame=args.camera_frame)
    return ReplayOptions(topics=topics, detector=args.detector, method=args.method, deskew=not args.no_deskew,
                         detect_period=args.detect_period, mission=args.mission, rig=args.rig, scene=args.scene,
                         max_gap=args.max_gap, rerun=args.rerun, progress=not args.quiet, overwrite=args.overwrite)


def run(args: argparse.Namespace) -> int:
    try:
        options = _options(args)
        flights = find_flights(list(args.flights))
    except (ValueError, BagError) as exc:
        print(f"insulator-rs replay: error: {exc}", file=sys.stderr)
        return 2
    fleet = len(flights) > 1 or any(p.is_dir() and not (p / "metadata.yaml").is_file() for p in args.flights)
    if not fleet:
        summary = replay_one(flights[0], args.out, options)
        score = _score(args.out, summary.get("scene"))
        _print_one(summary, score, args.out)
        return 0 if summary["status"] == "finished" else 1
    from insulator_rs.replay.fleet import replay_fleet

    fleet_summary = replay_fleet(flights, args.out, options, workers=args.workers, address=args.address)
    for f in fleet_summary["flights"]:
        score = _score(Path(f["out"]), f.get("scene")) if f.get("out") else None
        if score is not None:
            f.update({k: score[k] for k in ("insulators_matched", "insulators_in_scene", "mean_error_m")})
        print(f"{f['recording']}: {f['status'][:200]}: {f['insulators_found']} insulators")
    write_json(Path(args.out) / "fleet_summary.json", fleet_summary)
    print(f"fleet: {fleet_summary['flights_ok']}/{len(flights)} flights replayed, report in {args.out}")
    return 0 if fleet_summary["flights_ok"] == len(flights) else 1


def _score(out: Path, scene: str | None) -> dict[str, Any] | None:
    """After the replay: its report (``out/summary.json``) against the scene the recording names
    (a simulated flight's), written to ``score.json`` beside it; None without a scene or a report."""
    path = Path(out) / "summary.json"
    if not scene or not path.is_file():
        return None
    import json

    from insulator_rs.evaluation.scoring import score_flight, write_score
    from insulator_rs.sim.towers import load_tower

    try:
        summary = json.loads(path.read_text())
        if summary.get("run") != "replay" or "insulators" not in summary:
            return None  # a replay that could not start: nothing to score
        tower = load_tower(scene)
    except (ConfigError, ValueError, OSError) as exc:
        print(f"insulator-rs replay: note: {out} cannot be scored against scene {scene!r}: {exc}", file=sys.stderr)
        return None
    score = score_flight(summary, tower)
    write_score(Path(out), score)
    return score


def _print_one(summary: dict[str, Any], score: dict[str, Any] | None, out: Path) -> None:
    err = None if score is None else score.get("mean_error_m")
    speed = summary.get("speed_vs_real_time")
    print(f"{summary['status']}: {summary.get('frames', 0)} frames, {summary.get('frames_detected', 0)} "
          f"detected, {summary['insulators_found']} insulators"
          + (f" ({score['insulators_matched']} of {score['insulators_in_scene']} matched, mean error "
             f"{err:.3f} m, scored after the replay)" if score is not None and err is not None else "")
          + (f", {speed:.1f}x real time" if speed else "") + f"; report in {out}")
    if summary.get("attitude") == "yaw-only":
        print("insulator-rs replay: warning: every recorded pose is level (a yaw-only recording, from "
              "before the vehicle reported its attitude): the replay takes the body as level, as that "
              "flight did", file=sys.stderr)
