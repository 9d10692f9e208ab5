"""Clutter study (issue 22 item 5, "no gross localizations"): the default localization method
(``bounded``) through the flight's own :class:`~insulator_rs.perception.pipeline.PerceptionPipeline`
on seeded, varied cluttered insulator scenes.

Each scene (:func:`build_scene`) is one insulator string built as the tower builder builds it
(``sim.towers._shed_stack`` with tower A's strain or tower B's suspension proportions, length
1.2-2.2 m, metal fittings at both ends), horizontal (a strain string, drooping a few degrees) or
hanging, and around it, from the simulator's mesh primitives: 2-6 lattice members (4-10 cm
square sections) behind and beside it at 0.3-2 m, 1-3 conductors (1-3 cm radius, long, thin,
60 % return probability) crossing the view in front of, behind or near the string, and in about
half the scenes a cross-arm plate at the string's attached end. The vehicle flies past at 8-10 m
(1-2 m/s along the line, level or tilted by up to 5 degrees in roll and pitch, a small heading
error) and takes three detection events 0.2 s apart (the paper's three).

Sensing is the studies' (``evaluation.study_scenes``): the simulated Mid-360 (``sim.lidar``)
scans ending at each image and one scan later, odometry at 20 Hz with the localization study's
noise (2 cm, 0.2 degrees), the pipeline's live path (``add_pose``/``add_scan``/``process``). The
detection box is the true string's projected outline (its mesh vertices through the rig camera)
with 3 % of the box size of Gaussian jitter on each edge. The pipeline is built as the flight
builds it, ``rig_pipeline(rig, insulator_length=<true
length>)``, so its plausibility and shape gates apply.

Per scene the outcome is ``localized`` (error = distance between the estimated and true
centres), ``refused`` (the pipeline attempted a localization and refused it: a failure, an
implausible size, not an insulator, or ambiguous; the counter is recorded) or ``none`` (no
attempt: too few points in some event's box).

The public API is measured on the same clouds: ``ir.localize_bounded`` on the accumulated points
and boxes of the scene's fullest track, with the true length and none of the pipeline's gates
(``api_outcome``, ``api_error``). The bounded method's own ambiguity rule (fusion_core's
``ambiguity``: another, larger line in the box that fits the known length clearly better is taken,
one that fits about as well refuses the box) is what keeps a conductor in front of the string from
being reported there, as in the flight.

``python -m insulator_rs.evaluation.clutter_study --scenes 150 --out DIR`` writes
``clutter.csv`` and ``clutter_errors.png`` into DIR and prints the statistics.
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

import insulator_rs as ir
from insulator_rs.mavlink.frames import rotation_from_euler_ned_frd
from insulator_rs.evaluation.localization_study import StudyConfig
from insulator_rs.evaluation.study_scenes import POSE_RATE_HZ, envelope_purity, noisy_pose
from insulator_rs.perception.pipeline import AMBIGUOUS, EVENTS_PER_LOCALIZATION, PerceptionPipeline
from insulator_rs.perception.stack import rig_pipeline
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped
from insulator_rs.rig import SensorRig, simulator_rig
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.mesh import InstanceInfo, Mesh, box, cylinder, plane
from insulator_rs.sim.scene import SceneSpec, load_scene
from insulator_rs.sim.towers import (
    CONDUCTOR_COLOR,
    CONDUCTOR_ID_BASE,
    CONDUCTOR_RETURN_PROBABILITY,
    FITTINGS_ID,
    FITTINGS_INFO,
    GROUND_ID,
    GROUND_INFO,
    INSULATOR_COLOR,
    STEEL_INFO,
    TOWER_STEEL_ID,
    InsulatorTruth,
    _shed_stack,
    canonical_axis,
)

INSULATOR_ID = 1
PLATE_ID = TOWER_STEEL_ID  # a cross-arm plate is tower steel
EVENT_INTERVAL = 0.2  # s between detection events
BOX_JITTER = 0.03  # fraction of the box size, 1 sigma, on each edge
STRING_HEIGHT = 15.0  # m above the ground plane (which the Mid-360 then barely sees)


@dataclass(frozen=True)
class ClutterScene:
    """One generated scene: the mesh in W, the string's ground truth and what clutter it holds."""

    mesh: Mesh
    truth: InsulatorTruth
    style: str  # "A" (strain, horizontal) or "B" (suspension, hanging)
    members: int
    conductors: int
    plate: bool
    nearest_clutter: float  # m, smallest distance of a clutter element's axis line to the string's (infinite lines)


@dataclass(frozen=True)
class SceneRecord:
    """The outcome of one scene (m; NaN error when nothing was reported)."""

    scene: int
    style: str
    length: float
    standoff: float
    members: int
    conductors: int
    plate: bool
    nearest_clutter: float
    outcome: str  # "localized", "refused" or "none"
    reason: str  # refused: "failure", "implausible", "not_insulator" (":ambiguous": another, larger line
    # in the box, ir.AmbiguousLocalizationError); none: "few_points", "no_attempt"
    error: float
    error_axial: float
    error_depth: float  # signed, along the line of sight from the vehicle (+: beyond the true centre)
    angle_deg: float
    n_points: int  # points the localization rests on
    n_input: int  # accumulated culled points
    purity: float  # share of the accumulated points on the true string's envelope
    localizations: int
    tracks: int  # tracks the pipeline started (more than one: the box's anchor jumped between objects)
    api_outcome: str  # ir.localize_bounded alone on the fullest track: "localized", "ambiguous", "failure", "none"
    api_error: float  # m, its centre's distance to the true centre (NaN unless localized)


def _segment_distance(p0: np.ndarray, d0: np.ndarray, p1: np.ndarray, d1: np.ndarray) -> float:
    """Distance between the infinite lines p0 + s d0 and p1 + t d1."""
    n = np.cross(d0, d1)
    if np.linalg.norm(n) < 1e-9:
        return float(np.linalg.norm(np.cross(p1 - p0, d0)))
    return float(abs(np.dot(p1 - p0, n)) / np.linalg.norm(n))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def build_scene(rng: np.random.Generator, specs: dict[str, SceneSpec] | None = None) -> ClutterScene:
    """A seeded cluttered scene in W: x toward the side the vehicle flies on, y along the line, z up;
    the string's centre at (0, 0, STRING_HEIGHT)."""
    specs = specs or {k: load_scene(f"tower_{k.lower()}") for k in ("A", "B")}
    style = "A" if rng.random() < 0.5 else "B"
    spec = specs[style]
    length = float(rng.uniform(1.2, 2.2))
    ins = spec.insulators
    sheds = max(4, int(round(ins.sheds * length / ins.length)))
    spec = replace(spec, insulators=replace(ins, length=length, sheds=sheds))
    centre = np.array([0.0, 0.0, STRING_HEIGHT])
    if style == "A":
        tilt = math.radians(rng.uniform(3.0, 8.0))
        heading = math.radians(rng.uniform(-15.0, 15.0))  # off the line direction
        axis = np.array([math.sin(heading) * math.cos(tilt), math.cos(heading) * math.cos(tilt), -math.sin(tilt)])
    else:
        lean = math.radians(rng.uniform(0.0, 5.0))
        az = rng.uniform(0.0, 2 * math.pi)
        axis = np.array([math.sin(lean) * math.cos(az), math.sin(lean) * math.sin(az), -math.cos(lean)])
    start = centre - 0.5 * length * axis
    info = InstanceInfo(name="insulator 1", kind="insulator", color=INSULATOR_COLOR)
    parts: list[Mesh] = _shed_stack(spec, start, axis, INSULATOR_ID, info)
    fit = spec.insulators.fitting_length
    fit_r = 0.6 * spec.insulators.core_radius + 0.01
    attach = start - fit * axis
    free = start + length * axis + fit * axis
    parts.append(cylinder(attach, start, fit_r, instance_id=FITTINGS_ID, info=FITTINGS_INFO, segments=6))
    parts.append(cylinder(start + length * axis, free, fit_r, instance_id=FITTINGS_ID, info=FITTINGS_INFO,
                          segments=6))
    nearest = math.inf

    # Lattice members behind (x < 0) and beside (y, z offsets) the string, 0.3-2 m from its axis.
    n_members = int(rng.integers(2, 7))
    for _ in range(n_members):
        size = float(rng.uniform(0.04, 0.10))
        where = rng.choice(["behind", "beside"], p=[0.6, 0.4])
        dist = float(rng.uniform(0.3, 2.0))
        if where == "behind":
            offset = np.array([-dist, rng.uniform(-1.0, 1.0) * length / 2, rng.uniform(-0.5, 0.5)])
        else:
            side = rng.choice([-1.0, 1.0])
            perp = _unit(np.cross(axis, [1.0, 0.0, 0.0]))
            offset = side * dist * perp + np.array([rng.uniform(-0.5, 0.3), 0.0, 0.0])
        direction = _unit(rng.normal(size=3))
        half = 0.5 * float(rng.uniform(2.0, 6.0))
        c = centre + offset
        if rng.random() < 0.7:
            parts.append(cylinder(c - half * direction, c + half * direction, size / math.sqrt(2.0),
                                  instance_id=TOWER_STEEL_ID, info=STEEL_INFO, segments=4))
        else:
            # an angle-section stand-in as a box along the member
            u = direction
            v = _unit(np.cross(u, [0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.cross(u, [1.0, 0.0, 0.0]))
            R = np.column_stack([u, v, np.cross(u, v)])
            parts.append(box(c, [2 * half, size, size], instance_id=TOWER_STEEL_ID, info=STEEL_INFO, rotation=R))
        nearest = min(nearest, _segment_distance(centre, axis, c, direction))

    # Conductors crossing the view in front of, behind or near the string.
    n_cond = int(rng.integers(1, 4))
    for k in range(n_cond):
        where = rng.choice(["front", "behind", "near"])
        dx = {"front": rng.uniform(0.3, 2.0), "behind": -rng.uniform(0.3, 2.0),
              "near": rng.uniform(-0.3, 0.3)}[where]
        dz = rng.uniform(-1.2, 1.2) if where != "near" else rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 0.8)
        c = centre + np.array([dx, rng.uniform(-0.5, 0.5), dz])
        ang = math.radians(rng.uniform(-25.0, 25.0))  # mostly along the line, some across the view
        direction = _unit(np.array([math.sin(ang) * 0.3, math.cos(ang), math.sin(ang) * rng.uniform(-0.3, 0.3)]))
        radius = float(rng.uniform(0.01, 0.03))
        cinfo = InstanceInfo(name=f"conductor {k}", kind="conductor", color=CONDUCTOR_COLOR,
                             return_probability=CONDUCTOR_RETURN_PROBABILITY, thin=True)
        parts.append(cylinder(c - 15.0 * direction, c + 15.0 * direction, radius,
                              instance_id=CONDUCTOR_ID_BASE + k, info=cinfo, segments=6, capped=False))
        nearest = min(nearest, _segment_distance(centre, axis, c, direction))

    # Sometimes a cross-arm plate at the attached end.
    has_plate = bool(rng.random() < 0.5)
    if has_plate:
        normal = -axis
        pc = attach - 0.02 * axis + np.array([-rng.uniform(0.0, 0.4), 0.0, 0.0])
        parts.append(plane(pc, normal, (float(rng.uniform(0.8, 1.6)), float(rng.uniform(0.5, 1.0))),
                           instance_id=PLATE_ID, info=STEEL_INFO))
    ground = plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (200.0, 200.0), instance_id=GROUND_ID, info=GROUND_INFO)
    mesh = Mesh.concatenate([ground, *parts])
    truth = InsulatorTruth(instance_id=INSULATOR_ID, center=centre, axis=canonical_axis(axis), length=length,
                           side=1, arm=0, kind=spec.insulators.kind,
                           radius=spec.insulators.shed_radius)
    return ClutterScene(mesh, truth, style, n_members, n_cond, has_plate, nearest)


def _rpy_pose(position: np.ndarray, yaw: float, pitch: float, roll: float) -> np.ndarray:
    # the same ZYX Tait-Bryan composition as PX4's attitude (mavlink.frames), here in W
    T = np.eye(4)
    T[:3, :3] = rotation_from_euler_ned_frd(roll, pitch, yaw)
    T[:3, 3] = position
    return T


def _flight(rng: np.random.Generator, truth: InsulatorTruth) -> tuple[Callable[[float], np.ndarray], list[float], float]:
    """The pass: trajectory t -> T_w_b, the three image times and the standoff (m)."""
    standoff = float(rng.uniform(8.0, 10.0))
    speed = float(rng.uniform(1.0, 2.0)) * (1.0 if rng.random() < 0.5 else -1.0)
    start = truth.center + np.array([standoff, rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 0.5)])
    yaw = math.pi + math.radians(rng.uniform(-5.0, 5.0))
    tilted = rng.random() < 0.5
    pitch = math.radians(rng.uniform(-5.0, 5.0)) if tilted else 0.0
    roll = math.radians(rng.uniform(-5.0, 5.0)) if tilted else 0.0
    t0 = float(rng.uniform(0.0, 1000.0))  # a different part of the non-repetitive scan pattern
    velocity = np.array([0.0, speed, 0.0])

    def trajectory(t: float) -> np.ndarray:
        return _rpy_pose(start + velocity * (t - t0), yaw, pitch, roll)

    return trajectory, [t0 + (k + 1) * EVENT_INTERVAL for k in range(EVENTS_PER_LOCALIZATION)], standoff


def _box(vertices: np.ndarray, T_w_b: np.ndarray, rig: SensorRig, rng: np.random.Generator) -> np.ndarray | None:
    """The string's projected outline with BOX_JITTER on each edge, clipped to the image."""
    cam = rig.camera
    T_c_w = np.linalg.inv(T_w_b @ rig.T_b_c)
    uv, ok = ir.project_points(vertices, T_c_w, cam)
    if not np.any(ok):
        return None
    lo, hi = uv[ok].min(axis=0), uv[ok].max(axis=0)
    size = hi - lo
    b = np.concatenate([lo, hi]) + rng.normal(0.0, BOX_JITTER, 4) * np.tile(size, 2)
    wh = np.array([cam.width, cam.height, cam.width, cam.height], dtype=np.float64)
    b = np.clip(b, 0.0, wh)
    if b[2] - b[0] < 2 or b[3] - b[1] < 2:
        return None
    return b


def run_scene(index: int, seed: int, rig: SensorRig | None = None, lidar: Mid360 | None = None,
              specs: dict[str, SceneSpec] | None = None) -> tuple[SceneRecord, ClutterScene, PerceptionPipeline]:
    """One scene through the pipeline (seeded by ``seed`` and ``index``)."""
    rig = rig or simulator_rig()
    lidar = lidar or Mid360(rig.T_b_l)
    rng = np.random.default_rng([seed, index])
    scene = build_scene(rng, specs)
    truth = scene.truth
    trajectory, times, standoff = _flight(rng, truth)
    cfg = StudyConfig()
    pipe = rig_pipeline(rig, insulator_length=truth.length)
    verts = scene.mesh.vertices[np.unique(scene.mesh.triangles[scene.mesh.instance_ids == INSULATOR_ID])]
    image = np.broadcast_to(np.zeros(3, np.uint8), (rig.camera.height, rig.camera.width, 3))
    period = lidar.frame_period
    fed_until = times[0] - 1.0
    found = []
    for t in times:
        b = _box(verts, trajectory(t), rig, rng)
        if b is None:
            continue
        for tp in np.arange(fed_until + 1.0 / POSE_RATE_HZ, t + period + 1e-9, 1.0 / POSE_RATE_HZ):
            pipe.add_pose(PoseStamped(float(tp), noisy_pose(trajectory(float(tp)), rng, cfg)))
        fed_until = t + period
        for t_end in (t, t + period):
            frame = lidar.scan(scene.mesh, trajectory, t_end - period, seed=int(rng.integers(2**31)))
            pipe.add_scan(LidarScan(frame.points_l, frame.timestamps, lidar.T_b_l))
        found.extend(pipe.process(CameraFrame(t, image, rig.camera, rig.T_b_c), b[None, :]))
    c = pipe.counters
    track = max(pipe.tracks, key=lambda tr: len(tr.events)) if pipe.tracks else None
    acc = np.vstack(list(track.events)) if track is not None and track.events else np.zeros((0, 3))
    purity = envelope_purity(acc, truth)
    if found:
        loc = found[-1]
        d = loc.center - truth.center
        err = float(np.linalg.norm(d))
        axial = float(abs(np.dot(d, truth.axis)))
        sight = truth.center - trajectory(times[-1])[:3, 3]
        sight = sight - np.dot(sight, truth.axis) * truth.axis
        depth = float(np.dot(d, sight / np.linalg.norm(sight)))
        ang = math.degrees(math.acos(min(1.0, abs(float(np.dot(loc.axis, truth.axis))))))
        outcome, reason, n_pts = "localized", "", loc.n_points
    else:
        err = axial = depth = ang = math.nan
        n_pts = 0
        refused = {"failure": c.failures, "implausible": c.implausible, "not_insulator": c.not_insulator,
                   "unconfirmed": c.unconfirmed}
        reason = ",".join(k for k, v in refused.items() if v) or ""
        if pipe.not_insulator.get(AMBIGUOUS):
            reason = reason.replace("not_insulator", "not_insulator:ambiguous")
        outcome = "refused" if reason else "none"
        if outcome == "none":
            reason = "few_points" if c.few_points else "no_attempt"
    api_outcome, api_error = public_api_outcome(pipe, rig, truth)
    rec = SceneRecord(index, scene.style, truth.length, standoff, scene.members, scene.conductors, scene.plate,
                      scene.nearest_clutter, outcome, reason, err, axial, depth, ang, n_pts, len(acc), purity,
                      len(found), c.tracks, api_outcome, api_error)
    return rec, scene, pipe


@dataclass(frozen=True)
class TrackInputs:
    """What the bounded method reads for one track: its accumulated points in the body frame B of
    its latest event, its boxes (K, 4) px with the camera poses ``T_b_c`` (K, 4, 4) in that B, the
    camera, and ``T_w_b`` (that B in W)."""

    points_b: np.ndarray
    boxes: np.ndarray
    T_b_c: np.ndarray
    camera: ir.CameraModel
    T_w_b: np.ndarray


def fullest_track_inputs(pipe: PerceptionPipeline, rig: SensorRig) -> TrackInputs | None:
    """The inputs of the pipeline's track that gathered all EVENTS_PER_LOCALIZATION events with the most points (None
    without one)."""
    full = [t for t in pipe.tracks if len(t.events) == EVENTS_PER_LOCALIZATION]
    if not full:
        return None
    track = max(full, key=lambda t: sum(len(e) for e in t.events))
    T_w_b = track.views[-1][1] @ np.linalg.inv(rig.T_b_c)  # the rig camera's pose in W at the latest event
    T_b_w = np.linalg.inv(T_w_b)
    acc_w = np.vstack(list(track.events))
    return TrackInputs(acc_w @ T_b_w[:3, :3].T + T_b_w[:3, 3], np.array([b for b, _, _ in track.views]),
                       np.array([T_b_w @ T_w_c for _, T_w_c, _ in track.views]), track.views[-1][2], T_w_b)


def public_api_outcome(pipe: PerceptionPipeline, rig: SensorRig, truth: InsulatorTruth) -> tuple[str, float]:
    """``ir.localize_bounded`` on the fullest track's inputs (:func:`fullest_track_inputs`) given the
    true length: its outcome and centre error (m) against ``truth``. None of the pipeline's gates
    applies."""
    inputs = fullest_track_inputs(pipe, rig)
    if inputs is None:
        return "none", math.nan
    try:
        est = ir.localize_bounded(inputs.points_b, inputs.boxes, inputs.T_b_c, inputs.camera,
                                  insulator_length=truth.length)
    except ir.AmbiguousLocalizationError:
        return "ambiguous", math.nan
    except ir.LocalizationError:
        return "failure", math.nan
    center = inputs.T_w_b[:3, :3] @ np.asarray(est.center) + inputs.T_w_b[:3, 3]
    return "localized", float(np.linalg.norm(center - truth.center))


def run_clutter_study(n_scenes: int = 150, seed: int = 0,
                      progress: Callable[[int, int], None] | None = None) -> list[SceneRecord]:
    """``n_scenes`` seeded scenes through the pipeline; one record per scene."""
    rig = simulator_rig()
    lidar = Mid360(rig.T_b_l)
    specs = {k: load_scene(f"tower_{k.lower()}") for k in ("A", "B")}
    out = []
    for i in range(n_scenes):
        out.append(run_scene(i, seed, rig, lidar, specs)[0])
        if progress is not None:
            progress(i + 1, n_scenes)
    return out


def summarize_public_api(records: Sequence[SceneRecord]) -> dict[str, float]:
    """p99/max (m) of ``ir.localize_bounded``'s errors alone and its refusals, as a share of the
    scenes it was called on (those with a full track)."""
    e = np.array([r.api_error for r in records if r.api_outcome == "localized"], dtype=np.float64)
    called = sum(r.api_outcome != "none" for r in records)
    refused = sum(r.api_outcome in ("ambiguous", "failure") for r in records)
    return {"called": called, "localized": int(len(e)), "refused": refused,
            "ambiguous": sum(r.api_outcome == "ambiguous" for r in records),
            "refused_share": refused / called if called else math.nan,
            "p99": float(np.quantile(e, 0.99)) if len(e) else math.nan,
            "max": float(e.max()) if len(e) else math.nan}


def format_public_api(s: dict[str, float]) -> str:
    return (f"ir.localize_bounded alone on {int(s['called'])} scenes: {int(s['localized'])} localized, "
            f"{int(s['refused'])} refused ({100 * s['refused_share']:.1f} %, {int(s['ambiguous'])} ambiguous); "
            f"centre error [m] p99 {s['p99']:.3f}, max {s['max']:.3f}")


def summarize(records: Sequence[SceneRecord]) -> dict[str, float]:
    """mean/median/p95/p99/max of the reported errors (m) and the outcome counts."""
    e = np.array([r.error for r in records if r.outcome == "localized"], dtype=np.float64)
    s: dict[str, float] = {"scenes": len(records), "localized": int(len(e)),
                           "refused": sum(r.outcome == "refused" for r in records),
                           "none": sum(r.outcome == "none" for r in records)}
    if len(e):
        s.update(mean=float(e.mean()), median=float(np.median(e)), p95=float(np.quantile(e, 0.95)),
                 p99=float(np.quantile(e, 0.99)), max=float(e.max()))
    else:
        s.update(mean=math.nan, median=math.nan, p95=math.nan, p99=math.nan, max=math.nan)
    return s


def format_summary(s: dict[str, float]) -> str:
    return (f"{int(s['scenes'])} scenes: {int(s['localized'])} localized, {int(s['refused'])} refused, "
            f"{int(s['none'])} none; centre error [m] mean {s['mean']:.3f}, median {s['median']:.3f}, "
            f"p95 {s['p95']:.3f}, p99 {s['p99']:.3f}, max {s['max']:.3f}")


def write_outputs(records: Sequence[SceneRecord], out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with (out / "clutter.csv").open("w", newline="") as f:
        rows = [asdict(r) for r in records]
        if rows:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e = [r.error for r in records if r.outcome == "localized"]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.hist(e, bins=40)
    ax.set_xlabel("centre error [m]")
    ax.set_ylabel("scenes")
    ax.set_yscale("log")
    ax.set_title(f"Clutter study, bounded: {len(e)} localized of {len(records)} scenes")
    fig.tight_layout()
    fig.savefig(out / "clutter_errors.png", dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m insulator_rs.evaluation.clutter_study", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=150)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results/clutter"))
    parser.add_argument("--worst", type=int, default=8, help="print this many worst scenes")
    args = parser.parse_args(argv)
    start = time.monotonic()
    records = run_clutter_study(args.scenes, args.seed)
    elapsed = time.monotonic() - start
    write_outputs(records, args.out)
    print(format_summary(summarize(records)) + f"; {elapsed:.0f} s")
    print(format_public_api(summarize_public_api(records)))
    for r in sorted((r for r in records if r.outcome == "localized"), key=lambda r: -r.error)[:args.worst]:
        print(f"  scene {r.scene}: error {r.error:.3f} m (axial {r.error_axial:.3f}, {r.angle_deg:.1f} deg), "
              f"style {r.style}, L {r.length:.2f}, w {r.standoff:.1f}, members {r.members}, "
              f"conductors {r.conductors}, plate {r.plate}, nearest clutter {r.nearest_clutter:.2f} m, "
              f"points {r.n_points}/{r.n_input}, purity {r.purity:.2f}")
    reasons: dict[str, int] = {}
    for r in records:
        if r.outcome != "localized":
            reasons[f"{r.outcome}:{r.reason}"] = reasons.get(f"{r.outcome}:{r.reason}", 0) + 1
    print("  not reported:", reasons or "none")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
