"""``insulator-rs replay``: re-process recorded flights offline (one, or a fleet on Ray).

``replay FLIGHT`` reads an MCAP file, a rosbag2 folder (sqlite3 or MCAP) or a ROS 1 ``.bag``
and writes the flight's report to ``--out``. ``replay DIR`` with a folder of recordings (or
several FLIGHTs) re-processes each into ``--out/<name>/`` and writes ``fleet_summary.json``;
``--workers N`` runs them in parallel on Ray (a local Ray by default, ``--address`` joins a
running cluster: ``ray start --head`` on one machine, ``ray start --address=HEAD:6379`` on the
others, insulator_rs installed on all). One flight and a fleet run the same function,
:func:`replay_one`.

The mission (tower, line, inspection parameters) comes from the recording when insulator_rs
recorded it, else from ``--mission``; ground truth (errors in the report) from the scene the
recording names or ``--scene``. Topic and frame names default to livox_ros_driver2's, a ROS
camera driver's and PX4's (``/livox/lidar``, ``/camera/image_raw/compressed``,
``/fmu/out/vehicle_odometry`` or ``/odom``, ``/tf_static``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from insulator_rs.exceptions import BagError, ConfigError, ModelError
from insulator_rs.perception.pipeline import BOUNDED, METHODS
from insulator_rs.recording.types import Topics

DEFAULT_DETECTOR = "insulator-sim"
DETECT_CONF = 0.25  # as the flight's detection events


@dataclass(frozen=True)
class ReplayOptions:
    """Everything a replay of one flight needs besides its path (picklable, for Ray)."""

    topics: Topics = field(default_factory=Topics)
    detector: str = DEFAULT_DETECTOR
    method: str = BOUNDED  # the flight's default (inspect --method)
    deskew: bool = True
    detect_period: float = 0.0
    mission: str | None = None
    scene: str | None = None
    max_gap: float = 2.0
    rerun: bool = False
    progress: bool = False
    overwrite: bool = False


def replay_one(path: str | Path, out: str | Path, options: ReplayOptions) -> dict[str, Any]:
    """Replay one recorded flight into the report folder ``out``; its summary. A recording
    that cannot be opened or a bad option gives a summary with status ``failed: ...`` (and a
    report folder holding it), so a fleet goes on with the other flights."""
    from insulator_rs.recording.metadata import read_metadata
    from insulator_rs.recording.reader import FlightBag, bag_paths
    from insulator_rs.replay.run import ReplayRun, ReplaySettings

    path, out = Path(path), Path(out)
    try:
        bag_paths(path)  # a missing or foreign file is named before anything else
        meta = read_metadata(path)
        if options.mission is not None:
            from insulator_rs.mission.config import load_mission

            mission = load_mission(options.mission)
        else:
            recorded = meta.mission(path)
            if recorded is None:
                raise ConfigError(f"--mission: {path} does not carry its mission (not recorded by insulator_rs); "
                                  f"give the mission file")
            mission = recorded
        scene = options.scene or meta.scene or None
        truth = _ground_truth(scene) if scene else None
        detector = _detector(options.detector)
        settings = ReplaySettings(method=options.method, deskew=options.deskew, detect_period=options.detect_period,
                                  progress=options.progress)
        with FlightBag(path, options.topics, max_gap=options.max_gap) as bag:
            summary = ReplayRun(bag, out, mission=mission, detector=detector, settings=settings,
                                ground_truth=truth, rerun=options.rerun, overwrite=options.overwrite).run()
        summary["scene"] = scene
        summary["tower"] = f"{mission.tower.lat:.6f},{mission.tower.lon:.6f}"  # the tower's GPS names it
        return summary
    except (BagError, ConfigError, ModelError, ValueError) as exc:
        return _failed(path, out, str(exc))


def _failed(path: Path, out: Path, error: str) -> dict[str, Any]:
    """The summary of a replay that could not start; written to ``out`` when that is free
    (never over another run's report)."""
    summary = {"status": f"failed: {error}", "error": error, "recording": str(path), "insulators_found": 0,
               "insulators": []}
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def _ground_truth(scene: str) -> list[Any]:
    """The scene's true insulators (a simulated flight's; used only to score the replay)."""
    from insulator_rs.sim.towers import load_tower

    return list(load_tower(scene).insulators)


def _detector(name: str) -> Any:
    from insulator_rs.app.detect_command import open_detector
    from insulator_rs.ports.detector import NetworkDetector

    try:
        return NetworkDetector(open_detector(name, conf=DETECT_CONF))  # as the flight's --detector
    except ValueError as exc:
        raise ModelError(f"--detector: {exc}") from exc


def find_flights(paths: list[Path]) -> list[Path]:
    """The recordings among ``paths``: each a recording, or a folder of recordings (MCAP files,
    rosbag2 folders, ROS 1 bags) that is not itself a rosbag2 folder."""
    flights: list[Path] = []
    for p in paths:
        if p.is_dir() and not (p / "metadata.yaml").is_file():
            found = sorted(x for x in p.iterdir()
                           if (x.is_file() and x.suffix in (".mcap", ".bag"))
                           or (x.is_dir() and (x / "metadata.yaml").is_file()))
            if not found:
                raise BagError(f"{p}: no recordings in this folder (.mcap, .bag or rosbag2 folders)")
            flights.extend(found)
        else:
            flights.append(p)
    return flights


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("replay", help="re-process recorded flights (MCAP, rosbag2, ROS 1 bag) offline",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("flights", nargs="+", type=Path, help="recordings, or folders of recordings")
    p.add_argument("--out", type=Path, default=Path("replay_report"), help="report folder (created)")
    p.add_argument("--mission", default=None, help="mission file (default: the one the recording carries)")
    p.add_argument("--scene", default=None, help="scene whose ground truth scores the replay (simulated flights)")
    p.add_argument("--detector", default=DEFAULT_DETECTOR,
                   help=f"shipped model name or ONNX file (default {DEFAULT_DETECTOR})")
    p.add_argument("--method", default=BOUNDED, choices=METHODS,
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
                         detect_period=args.detect_period, mission=args.mission, scene=args.scene,
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
        _print_one(summary, args.out)
        return 0 if summary["status"] == "finished" else 1
    from insulator_rs.replay.fleet import replay_fleet

    fleet_summary = replay_fleet(flights, args.out, options, workers=args.workers, address=args.address)
    for f in fleet_summary["flights"]:
        print(f"{f['recording']}: {f['status'][:200]}: {f['insulators_found']} insulators")
    print(f"fleet: {fleet_summary['flights_ok']}/{len(flights)} flights replayed, report in {args.out}")
    return 0 if fleet_summary["flights_ok"] == len(flights) else 1


def _print_one(summary: dict[str, Any], out: Path) -> None:
    err = summary.get("mean_error_m")
    speed = summary.get("speed_vs_real_time")
    print(f"{summary['status']}: {summary.get('frames', 0)} frames, {summary.get('detection_events', 0)} detection "
          f"events, {summary['insulators_found']} insulators"
          + (f" (mean error {err:.3f} m)" if err is not None else "")
          + (f", {speed:.1f}x real time" if speed else "") + f"; report in {out}")

