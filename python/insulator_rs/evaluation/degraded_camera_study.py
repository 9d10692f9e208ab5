"""``insulator-rs eval degraded-camera``: whole flights with a degraded detection camera, camera only
beside camera + LiDAR (the LiDAR cue, ``[inspection] lidar_cue``).

Each cell is one simulated flight of a tower's example mission at the ``inspect`` defaults (the
in-process airframe, the shipped network that fits the simulator's frames, full-size photos
checked by that network), with the detector wrapped by one condition's degradation
(:mod:`insulator_rs.sim.camera_degradation`, seeded by ``--seed``):

* ``haze``: haze and low contrast in the detection frames before the network (:data:`HAZE`,
  :data:`CONTRAST`: the frames' RMS contrast x0.3; in 16 views of tower B's strings from 8-10 m
  the network then boxes 6 of the 17 it boxes on the clean frames);
* ``drop50`` / ``drop80``: 50 % / 80 % of the network's boxes on true insulators dropped at
  random, each box and frame drawn on its own;
* ``clean``: the network as shipped (not in the default set: the other studies fly it).

Each condition is flown twice, the cue off and on, everything else equal. From the scene's truth
after the flight (:func:`~insulator_rs.evaluation.scoring.score_flight`): strings found (a
localized insulator within MATCH_DISTANCE), strings photographed (found, and a photo taken for it
that the flight's own photo check found fit and that holds the whole true string), false finds
(localized insulators on no true string), flight time. Writes ``degraded_camera.md``,
``degraded_camera.json`` and ``degraded_camera.png`` (grouped bars) into ``--out``, and each
flight's report folder under it.
"""

from __future__ import annotations

import argparse
import sys
import time as wallclock
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from insulator_rs import bounds
from insulator_rs.evaluation.localization_study import MISSIONS_DIR, TOWERS
from insulator_rs.evaluation.scoring import MATCH_DISTANCE, score_flight, write_score
from insulator_rs.ports.detector import BoxDetector
from insulator_rs.report.folder import parse_out_folder
from insulator_rs.report.jsonfile import write_json

#: share of the scene's light lost to the haze, and the contrast left after it (the ``haze`` condition)
HAZE = 0.5
CONTRAST = 0.6


@dataclass(frozen=True)
class Condition:
    """A degradation of the detection camera: haze and contrast of the frames, share of the true
    boxes dropped; ``label`` is what the table and the figure call it."""

    label: str
    haze: float = 0.0
    contrast: float = 1.0
    drop: float = 0.0


CONDITIONS: dict[str, Condition] = {
    "clean": Condition("clean"),
    "haze": Condition(f"haze {HAZE:g} + contrast x{CONTRAST:g}", haze=HAZE, contrast=CONTRAST),
    "drop50": Condition("50 % of true boxes dropped", drop=0.5),
    "drop80": Condition("80 % of true boxes dropped", drop=0.8),
}
DEFAULT_CONDITIONS = ("drop80", "drop50", "haze")
CUES = {False: "camera only", True: "camera + LiDAR"}


@dataclass(frozen=True)
class DegradedCell:
    """One flight: tower, condition, cue; what it found against the truth; its detector's name."""

    tower: str
    condition: str
    cue: str
    strings: int
    found: int
    photographed: int
    false_finds: int
    flight_time_s: float
    status: str
    detector: str
    true_boxes: int | None
    dropped_boxes: int | None
    lidar_looks: int
    wall_s: float


def degrade(network: BoxDetector, condition: Condition, truth: Any, seed: int) -> BoxDetector:
    """``network`` as the condition degrades it: the frames hazed before it, then its true boxes
    (``truth``: the simulator's boxes of a frame) dropped."""
    from insulator_rs.sim.camera_degradation import DroppedTrueBoxes, HazedFrames

    detector: BoxDetector = network
    if condition.haze > 0 or condition.contrast < 1:
        detector = HazedFrames(detector, haze=condition.haze, contrast=condition.contrast)
    if condition.drop > 0:
        detector = DroppedTrueBoxes(detector, truth, fraction=condition.drop, seed=seed)
    return detector


def photographed_strings(score: dict[str, Any]) -> set[int]:
    """True strings (instance ids) with a fit photo that holds them whole, taken for a localized
    insulator on them (a score from :func:`score_flight`)."""
    on_truth = {r["id"]: r["gt_instance_id"] for r in score["insulators"]
                if r["error_m"] is not None and r["error_m"] < MATCH_DISTANCE}
    return {on_truth[p["insulator_id"]] for p in score["photos"]
            if p["insulator_id"] in on_truth and p["verdict"] is not None and p["verdict"].get("fitness") == "fit"
            and p["insulator_whole_in_frame"]}


def fly_cell(tower_key: str, condition_key: str, cue: bool, out: Path, *, seed: int = 0,
             scene: Path | None = None, mission_path: Path | None = None) -> DegradedCell:
    """Fly one cell (module docstring) into ``out`` (the report folder) and score it. ``scene`` and
    ``mission_path``: another scene and its mission than the tower's shipped ones."""
    from insulator_rs.flight.home import at_vehicle_home
    from insulator_rs.flight.settings import FlightSettings
    from insulator_rs.mission.config import load_mission
    from insulator_rs.perception.photo_check import PHOTO_DETECT_CONF
    from insulator_rs.ports.detector import default_model, open_network_detector
    from insulator_rs.sim.flight_assembly import assemble_flight, simulated_ports
    from insulator_rs.sim.mission_airframe import kinematic_vehicle
    from insulator_rs.sim.sensors import kinematic_true_pose
    from insulator_rs.sim.towers import load_tower

    wall0 = wallclock.perf_counter()
    condition = CONDITIONS[condition_key]
    tower = load_tower(str(scene) if scene is not None else TOWERS[tower_key])
    mission = load_mission(mission_path if mission_path is not None else MISSIONS_DIR / f"{TOWERS[tower_key]}.toml")
    mission = replace(mission, inspection=replace(mission.inspection, lidar_cue=cue))
    rig = mission.sensor_rig()
    vehicle = kinematic_vehicle(mission, seed)
    mission = at_vehicle_home(mission, vehicle)
    network = open_network_detector(default_model(live_camera=False))
    ports = simulated_ports(tower.mesh, kinematic_true_pose(vehicle), rig, seed=seed, network=network)
    detector = degrade(network, condition, ports.sensors.ground_truth_boxes, seed)
    # the photos are the zoom camera's, not degraded: checked as inspect checks them
    photo_detector = open_network_detector(str(network.network.path), conf=PHOTO_DETECT_CONF)
    flight = assemble_flight(mission, vehicle, ports.sensors, detector, out, rig=rig,
                             settings=FlightSettings(quiet=True), photo_camera=ports.photo_camera,
                             photo_detector=photo_detector)
    try:
        flight.loop.fly()
        summary = flight.loop.finish_report()
    finally:
        flight.vehicle.close()
        flight.sensors.close()
    score = score_flight(summary, tower)
    write_score(out, score)
    counts = getattr(detector, "counts", None)
    looks = [lk for lk in summary.get("second_looks", []) if lk.get("source") == "lidar string"]
    return DegradedCell(
        tower=tower_key, condition=condition_key, cue=CUES[cue], strings=score["insulators_in_scene"],
        found=score["insulators_matched"], photographed=len(photographed_strings(score)),
        false_finds=score["insulators_found"] - sum(1 for r in score["insulators"]
                                                    if r["error_m"] is not None and r["error_m"] < MATCH_DISTANCE),
        flight_time_s=round(float(summary["flight_time_s"]), 1), status=str(summary["status"]),
        detector=str(summary.get("detector", getattr(detector, "name", ""))),
        true_boxes=None if counts is None else int(counts["true_boxes"]),
        dropped_boxes=None if counts is None else int(counts["dropped"]),
        lidar_looks=len(looks), wall_s=round(wallclock.perf_counter() - wall0, 1))


def markdown(cells: Sequence[DegradedCell], seed: int) -> str:
    """The table: per tower and condition, camera only beside camera + LiDAR."""
    lines = [f"Degraded-camera study (seed {seed}): found / photographed of the tower's strings, false finds, "
             "flight time",
             "",
             "| tower | condition | camera only: found | photographed | false | flight s "
             "| camera + LiDAR: found | photographed | false | flight s |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    keys = list(dict.fromkeys((c.tower, c.condition) for c in cells))
    for tower, cond in keys:
        row = [f"| {tower} | {CONDITIONS[cond].label} "]
        for cue in CUES.values():
            c = next((x for x in cells if (x.tower, x.condition, x.cue) == (tower, cond, cue)), None)
            row.append("| – | – | – | – " if c is None else
                       f"| {c.found}/{c.strings} | {c.photographed}/{c.strings} | {c.false_finds} | {c.flight_time_s:.0f} ")
        lines.append("".join(row) + "|")
    return "\n".join(lines)


def plot(cells: Sequence[DegradedCell], path: Path) -> None:
    """Grouped bars, a column of panels per tower: above, strings found and photographed per
    condition (false finds written on the found bars); below, the flight time; camera only beside
    camera + LiDAR. Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    towers = sorted(dict.fromkeys(c.tower for c in cells))
    fig, axes = plt.subplots(2, len(towers), figsize=(6.5 * len(towers), 7.5), squeeze=False,
                             gridspec_kw={"height_ratios": [2, 1]})
    colors = {"camera only": "tab:blue", "camera + LiDAR": "tab:orange"}
    bars = [(what, cue, hatch) for cue in CUES.values() for what, hatch in (("found", None), ("photographed", "//"))]
    for col, tower in enumerate(towers):
        ax, ax_time = axes[0][col], axes[1][col]
        conds = [k for k in CONDITIONS if any(c.tower == tower and c.condition == k for c in cells)]
        width = 0.8 / len(bars)
        for ci, cond in enumerate(conds):
            for bi, (what, cue, hatch) in enumerate(bars):
                c = next((x for x in cells if (x.tower, x.condition, x.cue) == (tower, cond, cue)), None)
                if c is None:
                    continue
                value = getattr(c, what)
                x = ci - 0.4 + (bi + 0.5) * width
                ax.bar(x, value, width, color=colors[cue], hatch=hatch, edgecolor="black",
                       label=f"{what}, {cue}" if ci == 0 else None)
                note = f"\n{c.false_finds} false" if what == "found" else ""
                ax.text(x, value + 0.05, f"{value}{note}", ha="center", va="bottom", fontsize=7)
            for k, cue in enumerate(CUES.values()):
                c = next((x for x in cells if (x.tower, x.condition, x.cue) == (tower, cond, cue)), None)
                if c is None:
                    continue
                x = ci - 0.2 + k * 0.4
                ax_time.bar(x, c.flight_time_s / 60, 0.4, color=colors[cue], edgecolor="black",
                            label=cue if ci == 0 else None)
                ax_time.text(x, c.flight_time_s / 60, f"{c.flight_time_s / 60:.1f}", ha="center", va="bottom",
                             fontsize=7)
        strings = max(c.strings for c in cells if c.tower == tower)
        ax.axhline(strings, color="grey", lw=0.8, ls="--")
        labels = [CONDITIONS[k].label.replace(" of true boxes", "\nof true boxes") for k in conds]
        for a in (ax, ax_time):
            a.set_xticks(range(len(conds)), labels, fontsize=8)
            a.set_xlim(-0.5, len(conds) - 0.5)
        ax.set_ylim(0, strings * 1.3)
        ax.set_ylabel("strings")
        ax.set_title(f"tower {tower}: {strings} strings")
        ax.legend(fontsize=7, loc="lower left")
        ax_time.set_ylabel("flight time [min]")
        ax_time.set_ylim(0, max(c.flight_time_s for c in cells if c.tower == tower) / 60 * 1.25)
        ax_time.legend(fontsize=7, loc="lower left")
    fig.suptitle("Degraded detection camera: camera only vs camera + LiDAR cue (insulator-rs eval degraded-camera)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_results(out: Path, cells: Sequence[DegradedCell], seed: int) -> None:
    """``degraded_camera.md``, ``.json`` and ``.png`` in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "degraded_camera.md").write_text(markdown(cells, seed) + "\n", encoding="utf-8")
    write_json(out / "degraded_camera.json", {
        "seed": seed, "conditions": {k: asdict(v) for k, v in CONDITIONS.items()},
        "cells": [asdict(c) for c in cells]})
    plot(cells, out / "degraded_camera.png")


def flown_cells(out: Path) -> list[DegradedCell]:
    """The cells ``degraded_camera.json`` in ``out`` already holds ([] when there is none)."""
    import json

    path = out / "degraded_camera.json"
    if not path.is_file():
        return []
    return [DegradedCell(**c) for c in json.loads(path.read_text(encoding="utf-8"))["cells"]]


def run_study(out: Path, towers: Sequence[str], conditions: Sequence[str], *, seed: int = 0, resume: bool = False,
              say: Callable[[str], None] = print) -> list[DegradedCell]:
    """Every cell, one flight at a time (tower, then condition, cue off then on); the results are
    rewritten after each flight, so a study cut short keeps what it flew, and ``resume`` takes the
    cells ``out`` already holds (same seed) instead of flying them again."""
    kept = flown_cells(out) if resume else []
    if kept and resume:
        import json

        flown_seed = json.loads((out / "degraded_camera.json").read_text(encoding="utf-8"))["seed"]
        if flown_seed != seed:
            raise ValueError(f"--resume: {out} holds a study flown with seed {flown_seed}, not {seed}")
    cells: list[DegradedCell] = []
    for tower in towers:
        for cond in conditions:
            for cue, cue_name in CUES.items():
                cell = next((c for c in kept if (c.tower, c.condition, c.cue) == (tower, cond, cue_name)), None)
                if cell is None:
                    cell = fly_cell(tower, cond, cue, out / f"tower_{tower}" / cond / ("cue" if cue else "camera"),
                                    seed=seed)
                    say(f"tower {tower}, {CONDITIONS[cond].label}, {cell.cue}: {cell.status}, found "
                        f"{cell.found}/{cell.strings}, photographed {cell.photographed}, false {cell.false_finds}, "
                        f"flight {cell.flight_time_s:.0f} s, dropped {cell.dropped_boxes}/{cell.true_boxes} true "
                        f"boxes, {cell.lidar_looks} LiDAR looks (wall {cell.wall_s:.0f} s)")
                cells.append(cell)
                # the cells flown so far, and those kept that this run does not fly
                rest = [c for c in kept if (c.tower, c.condition, c.cue) not in
                        {(x.tower, x.condition, x.cue) for x in cells}]
                write_results(out, cells + rest, seed)
    return cells


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``insulator-rs eval degraded-camera``."""
    parser.add_argument("--towers", nargs="+", choices=sorted(TOWERS), default=["B", "A"],
                        help="towers to fly (default B A)")
    parser.add_argument("--conditions", nargs="+", choices=list(CONDITIONS), default=list(DEFAULT_CONDITIONS),
                        help="degradations to fly, each camera only and with the LiDAR cue "
                             f"(default {' '.join(DEFAULT_CONDITIONS)})")
    parser.add_argument("--seed", type=bounds.option("--seed"), default=0,
                        help="seed of the simulator and of the dropped boxes (integer, 0 to 2^32-1)")
    parser.add_argument("--out", type=parse_out_folder, default=Path("results/degraded_camera"),
                        help="folder for the table, the figure and each flight's report (created)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the cells --out already holds (its degraded_camera.json, the same seed) and fly "
                             "only the others")


def run(args: argparse.Namespace) -> int:
    """Entry point: flies the cells, prints a line per flight and the table."""
    try:
        cells = run_study(args.out, args.towers, args.conditions, seed=args.seed, resume=args.resume,
                          say=lambda line: print(line, file=sys.stderr, flush=True))
    except ValueError as exc:
        print(f"insulator-rs eval degraded-camera: error: {exc}", file=sys.stderr)
        return 2
    print(markdown(cells, args.seed))
    return 0
