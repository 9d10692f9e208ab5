"""Replay of one recorded flight into a report folder: the function a single ``replay`` and
every task of a fleet run (:func:`replay_one`). Library code: options in, summary out; the
``replay`` command (``insulator_rs.app.replay_command``) parses the options and scores the
reports afterwards where a scene is known."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from insulator_rs.exceptions import BagError, ConfigError, ModelError
from insulator_rs.mission.config import Mission
from insulator_rs.models import SIMULATOR_MODEL
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.ports.detector import DETECT_CONF, BoxDetector, open_network_detector
from insulator_rs.recording.metadata import FlightMetadata
from insulator_rs.recording.types import Topics
from insulator_rs.report.jsonfile import write_json
from insulator_rs.report.summary import failed_summary
from insulator_rs.rig import load_rig

DEFAULT_DETECTOR = SIMULATOR_MODEL  # the network the simulated flights fly with


@dataclass(frozen=True)
class ReplayOptions:
    """Everything a replay of one flight needs besides its path (picklable, for Ray)."""

    topics: Topics = field(default_factory=Topics)
    detector: str = DEFAULT_DETECTOR
    method: LocalizationMethod = DEFAULT_METHOD  # the flight's default (inspect --method)
    deskew: bool = True
    detect_period: float = 0.0
    mission: str | None = None
    rig: str | None = None  # a rig file for the mission's (its [camera] latency_s: a later calibration)
    scene: str | None = None
    max_gap: float = 2.0
    rerun: bool = False
    progress: bool = False
    overwrite: bool = False
    read_ahead: bool = True  # decode and detect in a thread ahead of the loop (replay/lookahead.py)
    # network runs at once while reading ahead (None: one a core this process may use); a Ray
    # fleet gives each flight its share of the cores (replay/fleet.py)
    network_threads: int | None = None


def replay_one(path: str | Path, out: str | Path, options: ReplayOptions) -> dict[str, Any]:
    """Replay one recorded flight into the report folder ``out``; its summary (plus ``scene``:
    the scene the recording names or ``options.scene``, and ``tower``: its GPS). A recording
    that cannot be opened or a bad option gives a summary with status ``failed: ...`` (and a
    report folder holding it), so a fleet goes on with the other flights."""
    from insulator_rs.mission.config import load_mission
    from insulator_rs.recording.metadata import read_metadata
    from insulator_rs.recording.reader import FlightBag, bag_paths
    from insulator_rs.replay.run import ReplayRun, ReplaySettings

    path, out = Path(path), Path(out)
    try:
        bag_paths(path)  # a missing or foreign file is named before anything else
        meta = read_metadata(path)
        if options.mission is not None:  # takeoff = "home" there too: from where the flight took off
            mission = meta.at_flown_takeoff(load_mission(options.mission))
        else:
            recorded = meta.mission(path)
            if recorded is None:
                raise ConfigError(f"--mission: {path} does not carry its mission (not recorded by insulator_rs); "
                                  f"give the mission file")
            mission = recorded
        if options.rig is not None:
            mission = replace(mission, rig=load_rig(options.rig))
        # read ahead, the network runs on one thread a run, one run a core (replay/lookahead.py)
        ahead = options.read_ahead and options.detect_period == 0
        detector = open_detector_by_name(options.detector, threads=1 if ahead else None)
        latency = camera_latency(meta, mission)
        settings = ReplaySettings(method=options.method, deskew=options.deskew, detect_period=options.detect_period,
                                  progress=options.progress, camera_shift_s=latency["shift_s"],
                                  read_ahead=options.read_ahead, network_threads=options.network_threads)
        # a recording of ours logs each scan at its window's end (McapRecorder.scan)
        with FlightBag(path, options.topics, max_gap=options.max_gap, scan_windows=bool(meta.mission_text)) as bag:
            summary = ReplayRun(bag, out, mission=mission, detector=detector, settings=settings,
                                rerun=options.rerun, overwrite=options.overwrite).run().as_dict()
        summary["camera_latency"] = latency
        summary["scene"] = options.scene or meta.scene or None
        summary["tower"] = f"{mission.tower.lat:.6f},{mission.tower.lon:.6f}"  # the tower's GPS names it
        return summary
    except (BagError, ConfigError, ModelError, ValueError) as exc:
        return failed(path, out, str(exc))


def camera_latency(meta: FlightMetadata, mission: Mission) -> dict[str, Any]:
    """How much earlier than their recorded stamps the frames were exposed (``shift_s``): the
    rig's ``[camera] latency_s`` as it is now (``calibrate time-offset --rig`` writes it after the
    flight) less what the flight's camera already subtracted (``recorded_s``, as the recording
    says; a recording from before it said: nothing is shifted, and ``note`` says why)."""
    rig_latency = mission.rig.camera_latency_s if mission.rig is not None else 0.0
    recorded = meta.recorded_camera_latency()
    record: dict[str, Any] = {"rig_s": rig_latency, "recorded_s": recorded,
                              "shift_s": 0.0 if recorded is None else rig_latency - recorded}
    if recorded is None and rig_latency:
        record["note"] = ("the recording does not say which camera latency its frame stamps carry: "
                          "the rig's latency_s is not applied")
    return record


def failed(path: Path, out: Path, error: str) -> dict[str, Any]:
    """The summary of a replay that could not start; written to ``out`` when that is free
    (never over another run's report)."""
    summary = failed_summary("replay", error, recording=str(path))
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "summary.json", summary)
    return summary


def open_detector_by_name(name: str, *, threads: int | None = None) -> BoxDetector:
    """The shipped network ``name`` or an ONNX file, at the flight's confidence threshold;
    ``threads`` a run (None: onnxruntime's default); its threads do not spin between runs (the
    replay's loop needs the core: replay/lookahead.py)."""
    try:
        return open_network_detector(name, conf=DETECT_CONF, threads=threads, spinning=False)
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
