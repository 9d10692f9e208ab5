"""``insulator-rs calibrate time-offset FLIGHT``: the camera's time offset against the LiDAR,
measured on a recorded flight (:mod:`insulator_rs.replay.time_offset`), written into a rig
file's ``[camera] latency_s`` with ``--rig`` (added to the value there: the recording's stamps
were made with it applied)."""

from __future__ import annotations

import argparse
import json
import sys

from insulator_rs.exceptions import BagError, ConfigError, ModelError
from insulator_rs.replay.batch import DEFAULT_DETECTOR, open_detector_by_name
from insulator_rs.replay.time_offset import MAX_OFFSET, calibrate_time_offset
from insulator_rs.rig import load_rig, write_camera_latency


def run_time_offset(args: argparse.Namespace) -> int:
    try:
        rig = load_rig(args.rig) if args.rig is not None else None  # a bad rig file refused before the work
        detector = open_detector_by_name(args.detector)
        result = calibrate_time_offset(args.flight, detector, max_offset=args.max_offset)
        out = {"flight": str(args.flight), "offset_s": round(result.offset_s, 4), "score": round(result.score, 4),
               "score_at_zero": round(result.score_at_zero, 4), "boxes": result.boxes, "frames": result.frames}
        if rig is not None:
            latency = rig.camera_latency_s + result.offset_s
            write_camera_latency(args.rig, latency)
            out |= {"rig": str(args.rig), "latency_s": round(latency, 4)}
    except (BagError, ConfigError, ModelError, ValueError, OSError) as exc:
        print(f"insulator-rs calibrate time-offset: error: {exc}", file=sys.stderr)
        return 2
    if args.curve:
        out["curve"] = result.curve
    print(json.dumps(out))
    return 0


def _max_offset(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not 0 < value <= 0.5:
        raise argparse.ArgumentTypeError(f"must be in (0, 0.5] s, got {text}")
    return value


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser("calibrate", help="calibrate the sensor rig from a recorded flight")
    sub = parser.add_subparsers(dest="calibrate_command", required=True)
    p = sub.add_parser("time-offset", help="the camera's time offset against the LiDAR (s, + = frames stamped late)")
    p.add_argument("flight", help="a recorded flight (.mcap, .bag or a rosbag2 folder)")
    p.add_argument("--rig", default=None, help="rig file (TOML) whose [camera] latency_s gets the result "
                        "(default: printed only)")
    p.add_argument("--detector", default=DEFAULT_DETECTOR, help="shipped network name or ONNX file")
    p.add_argument("--max-offset", type=_max_offset, default=MAX_OFFSET,
                   help=f"s: offsets scanned, either sign (default {MAX_OFFSET:g})")
    p.add_argument("--curve", action="store_true", help="also print the coarse scan (offset, score)")
    p.set_defaults(func=run_time_offset)
