"""Parametric power-line towers: a :class:`~insulator_rs.sim.scene.SceneSpec` made into a mesh.

:func:`build_tower` builds, in the world frame W (ENU, metres, the tower's base
centre at the origin), the lattice body (four legs, X-bracing on every face,
an earth-wire peak), the lattice cross-arms, the insulator strings as shed
stacks (a core rod with large and small sheds alternating, plus the metal
fittings at both ends), the conductors hanging from the insulators as catenaries
toward both neighbouring towers (and the jumper loops of strain towers), and
the ground. It returns the mesh and the ground truth of every insulator.

Instance ids: 0 ground, 1..N the insulators (in the order of
:attr:`Tower.insulators`), :data:`TOWER_STEEL_ID` the lattice,
:data:`FITTINGS_ID` the insulator hardware, :data:`CONDUCTOR_ID_BASE` + k the
k-th conductor or jumper, :data:`OBSTACLE_ID_BASE` + k the scene's k-th obstacle (``[[obstacles]]``:
things beside the tower that its model does not hold; built in W, not rotated with the tower).

Tower-local frame: x across the line (the '+' side), y along the line (toward
neighbour 1), z up; it is rotated into W by the line direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from insulator_rs.sim.mesh import InstanceInfo, Mesh, cylinder, plane
from insulator_rs.sim.scene import CrossArmSpec, SceneSpec, load_scene

GROUND_ID = 0
TOWER_STEEL_ID = 500
FITTINGS_ID = 501
CONDUCTOR_ID_BASE = 1000
OBSTACLE_ID_BASE = 3000
OBSTACLE_COLOR = (0.45, 0.36, 0.26)  # a weathered wooden pole

GROUND_INFO = InstanceInfo(name="ground", kind="ground", color=(0.32, 0.40, 0.22))
#: m: the height of every built scene's ground plane in W (the tower stands on it)
GROUND_Z = 0.0
STEEL_INFO = InstanceInfo(name="tower steel", kind="tower", color=(0.55, 0.57, 0.58))
FITTINGS_INFO = InstanceInfo(name="insulator fittings", kind="other", color=(0.60, 0.60, 0.62))
INSULATOR_COLOR = (0.42, 0.52, 0.50)  # weathered glass/composite grey-green
CONDUCTOR_COLOR = (0.62, 0.63, 0.64)
# A stranded conductor of 2-3 cm returns a Mid-360 echo only part of the time
# (beam footprint ~ 2-3 cm at 10 m, so the wire fills a fraction of it).
CONDUCTOR_RETURN_PROBABILITY = 0.6

# Facets of the round parts: sheds need enough facets for a round silhouette;
# the lattice angle sections are square (4 facets).
SHED_SEGMENTS = 16
CONDUCTOR_SEGMENTS = 6
MEMBER_SEGMENTS = 4
JUMPER_SEGMENT_LENGTH = 0.25  # m
# Radius of a shed where it meets the core, as a multiple of the core radius.
SHED_ROOT_FACTOR = 1.3


@dataclass(frozen=True)
class InsulatorTruth:
    """Ground truth of one insulator in W.

    center: m, middle of the shed stack. axis: unit vector along the stack, sign
    canonical (largest-|component| positive, as ``ir.localize`` reports).
    length: m of the shed stack. side: +1 or -1, the side of the line the
    insulator is on (sign of its offset along :attr:`SceneSpec.lateral_direction`).
    instance_id: its id in the mesh. arm: index of its cross-arm in the spec.
    kind: "strain" or "suspension". radius: m, largest shed radius.
    """

    instance_id: int
    center: np.ndarray
    axis: np.ndarray
    length: float
    side: int
    arm: int
    kind: str
    radius: float

    @property
    def end_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The two ends of the shed stack in W (m)."""
        half = 0.5 * self.length * self.axis
        return self.center - half, self.center + half


@dataclass(frozen=True)
class Tower:
    """A built scene: the mesh in W, the insulators' ground truth and the spec it came from."""

    spec: SceneSpec
    mesh: Mesh
    insulators: tuple[InsulatorTruth, ...]

    @property
    def max_height(self) -> float:
        """m, highest point of the tower (body plus earth-wire peak)."""
        return self.spec.body.height + self.spec.body.peak_height

    @property
    def max_width(self) -> float:
        """m, largest horizontal extent of the tower across the line (tip to tip of the widest arm)."""
        return 2.0 * max(arm.reach for arm in self.spec.cross_arms)

    def insulator(self, instance_id: int) -> InsulatorTruth:
        for ins in self.insulators:
            if ins.instance_id == instance_id:
                return ins
        raise ValueError(f"instance_id: no insulator with id {instance_id}")


def canonical_axis(v: np.ndarray) -> np.ndarray:
    """Unit vector with its largest-|component| positive (the sign convention of ``ir.localize``)."""
    v = np.asarray(v, dtype=np.float64)
    v = v / np.linalg.norm(v)
    return v if v[int(np.argmax(np.abs(v)))] > 0 else -v


def _member(p0: np.ndarray, p1: np.ndarray, size: float, instance_id: int = TOWER_STEEL_ID,
            info: InstanceInfo = STEEL_INFO) -> Mesh:
    """A lattice member of square section ``size`` (m) between two points."""
    return cylinder(p0, p1, size / math.sqrt(2.0), instance_id=instance_id, info=info,
                    segments=MEMBER_SEGMENTS)


def _body_half_width(spec: SceneSpec, z: float) -> float:
    body = spec.body
    return 0.5 * (body.base_width + (body.top_width - body.base_width) * z / body.height)


def _lattice_body(spec: SceneSpec) -> list[Mesh]:
    body = spec.body
    parts: list[Mesh] = []
    signs = ((1, 1), (-1, 1), (-1, -1), (1, -1))  # corners in order around the section
    levels = np.linspace(0.0, body.height, body.panels + 1)

    def corners(z: float) -> list[np.ndarray]:
        h = _body_half_width(spec, z)
        return [np.array([sx * h, sy * h, z]) for sx, sy in signs]

    for z0, z1 in zip(levels[:-1], levels[1:]):
        c0, c1 = corners(z0), corners(z1)
        for k in range(4):
            parts.append(_member(c0[k], c1[k], body.leg_size))
            nk = (k + 1) % 4
            # X-bracing on the face between corner k and k+1.
            parts.append(_member(c0[k], c1[nk], body.brace_size))
            parts.append(_member(c0[nk], c1[k], body.brace_size))
            # Horizontal strut at the top of the panel.
            parts.append(_member(c1[k], c1[nk], body.brace_size))
    if body.peak_height > 0.0:
        apex = np.array([0.0, 0.0, body.height + body.peak_height])
        for c in corners(body.height):
            parts.append(_member(c, apex, body.brace_size))
    return parts


def _cross_arm(spec: SceneSpec, arm: CrossArmSpec) -> list[Mesh]:
    """A lattice cross-arm on both sides: two lower chords, two upper chords, web and ties."""
    body = spec.body
    parts: list[Mesh] = []
    half_w = _body_half_width(spec, arm.height)
    half_y = min(0.5 * arm.width, half_w)
    for sx in (1.0, -1.0):
        tip = np.array([sx * arm.reach, 0.0, arm.height])
        roots_low = [np.array([sx * half_w, sy * half_y, arm.height]) for sy in (1.0, -1.0)]
        roots_up = [np.array([sx * _body_half_width(spec, arm.height + arm.depth), sy * half_y,
                              arm.height + arm.depth]) for sy in (1.0, -1.0)]
        for low, up in zip(roots_low, roots_up):
            parts.append(_member(low, tip, body.leg_size))
            parts.append(_member(up, tip, body.brace_size * 1.2))
            # Zig-zag web between the lower and upper chord of this side face.
            n_web = max(2, int(math.ceil((arm.reach - half_w) / 1.0)))
            t = np.linspace(0.0, 1.0, n_web + 1)
            lows = [low + ti * (tip - low) for ti in t]
            ups = [up + ti * (tip - up) for ti in t]
            for i in range(n_web):
                a, b = (lows[i], ups[i + 1]) if i % 2 == 0 else (ups[i], lows[i + 1])
                if np.linalg.norm(b - a) > 1e-6:
                    parts.append(_member(a, b, body.brace_size))
        # Horizontal ties between the two lower chords along the arm.
        n_tie = max(2, int(math.ceil((arm.reach - half_w) / 1.5)))
        for ti in np.linspace(0.0, 1.0, n_tie + 1)[:-1]:
            a = roots_low[0] + ti * (tip - roots_low[0])
            b = roots_low[1] + ti * (tip - roots_low[1])
            if np.linalg.norm(b - a) > 1e-6:
                parts.append(_member(a, b, body.brace_size))
    return parts


def _shed_stack(spec: SceneSpec, start: np.ndarray, axis: np.ndarray, instance_id: int,
                info: InstanceInfo) -> list[Mesh]:
    """Core rod plus 2*sheds-1 conical sheds alternating large/small along ``axis`` from ``start``."""
    ins = spec.insulators
    end = start + ins.length * axis
    parts = [cylinder(start, end, ins.core_radius, instance_id=instance_id, info=info,
                      segments=SHED_SEGMENTS // 2)]
    n = 2 * ins.sheds - 1
    # Sheds spread evenly, the first and last one shed-thickness inside the ends.
    centres = np.linspace(ins.shed_thickness, ins.length - ins.shed_thickness, n)
    # Each shed is a cone frustum, wide at its skirt (the end toward the free end of the
    # string, i.e. downward on a suspension string) and narrow at its root on the core, as real
    # sheds slope: a flat disc would be seen edge-on at grazing incidence by a LiDAR level with
    # it and return almost nothing.
    root = ins.core_radius * SHED_ROOT_FACTOR
    for i, s in enumerate(centres):
        r = ins.shed_radius if i % 2 == 0 else ins.small_shed_radius
        c = start + s * axis
        half = 0.5 * ins.shed_thickness * axis
        parts.append(cylinder(c - half, c + half, root, radius_end=r, instance_id=instance_id,
                              info=info, segments=SHED_SEGMENTS))
    return parts


def _catenary_points(p: np.ndarray, q: np.ndarray, a: float, max_horizontal: float,
                     step: float) -> np.ndarray:
    """Points of the catenary z = a cosh((s - s0)/a) + c from p toward q (s: horizontal distance).

    Only the first ``max_horizontal`` metres are returned, sampled every ``step`` m.
    """
    d = q[:2] - p[:2]
    span = float(np.linalg.norm(d))
    dz = float(q[2] - p[2])
    # Lowest point s0 of the catenary through both ends (closed form).
    s0 = 0.5 * span - a * math.asinh(dz / (2.0 * a * math.sinh(span / (2.0 * a))))
    c = p[2] - a * math.cosh(-s0 / a)
    length = min(span, max_horizontal)
    n = max(1, int(math.ceil(length / step)))
    s = np.linspace(0.0, length, n + 1)
    xy = p[:2] + np.outer(s / span, d)
    z = a * np.cosh((s - s0) / a) + c
    return np.column_stack([xy, z])


def _polyline(points: np.ndarray, radius: float, instance_id: int, info: InstanceInfo) -> list[Mesh]:
    return [cylinder(a, b, radius, instance_id=instance_id, info=info, segments=CONDUCTOR_SEGMENTS,
                     capped=False) for a, b in zip(points[:-1], points[1:])]


def _tower_rotation(spec: SceneSpec) -> np.ndarray:
    """3x3 rotation from the tower-local frame (x lateral, y along the line, z up) into W."""
    return np.column_stack([spec.lateral_direction, spec.line_direction, (0.0, 0.0, 1.0)])


def build_tower(spec: SceneSpec) -> Tower:
    """Build the mesh of ``spec`` in W and the ground truth of every insulator."""
    R = _tower_rotation(spec)
    ins_spec = spec.insulators
    cond = spec.conductors
    local_parts: list[Mesh] = _lattice_body(spec)
    for arm in spec.cross_arms:
        local_parts.extend(_cross_arm(spec, arm))

    # Neighbour positions in the tower-local frame (their towers are assumed alike).
    neighbours_local = [R.T @ np.asarray(n, dtype=np.float64) for n in spec.neighbours]

    truths: list[InsulatorTruth] = []
    conductor_paths: list[np.ndarray] = []  # local-frame polylines
    next_id = 1
    tilt = math.radians(ins_spec.tilt_deg)
    for arm_index, arm in enumerate(spec.cross_arms):
        for sx in (1.0, -1.0):
            tip = np.array([sx * arm.reach, 0.0, arm.height])
            if ins_spec.kind == "strain":
                directions = []
                for nb in neighbours_local:
                    # Toward the same arm tip on the neighbour (strings run parallel to the line).
                    h = nb[:2] + np.array([tip[0], 0.0]) - tip[:2]
                    h = h / np.linalg.norm(h)
                    directions.append(np.array([h[0] * math.cos(tilt), h[1] * math.cos(tilt),
                                                -math.sin(tilt)]))
            else:
                directions = [np.array([0.0, 0.0, -1.0])]
            free_ends: list[np.ndarray] = []
            for axis in directions:
                iid = next_id
                next_id += 1
                stack_start = tip + ins_spec.fitting_length * axis
                stack_end = stack_start + ins_spec.length * axis
                free_end = stack_end + ins_spec.fitting_length * axis
                info = InstanceInfo(name=f"insulator {iid}", kind="insulator", color=INSULATOR_COLOR)
                local_parts.extend(_shed_stack(spec, stack_start, axis, iid, info))
                fitting_r = 0.6 * ins_spec.core_radius + 0.01
                if ins_spec.fitting_length > 0.0:
                    local_parts.append(cylinder(tip, stack_start, fitting_r, instance_id=FITTINGS_ID,
                                                info=FITTINGS_INFO, segments=6))
                    local_parts.append(cylinder(stack_end, free_end, fitting_r,
                                                instance_id=FITTINGS_ID, info=FITTINGS_INFO,
                                                segments=6))
                centre_local = 0.5 * (stack_start + stack_end)
                truths.append(InsulatorTruth(
                    instance_id=iid,
                    center=R @ centre_local,
                    axis=canonical_axis(R @ axis),
                    length=ins_spec.length,
                    side=1 if sx > 0 else -1,
                    arm=arm_index,
                    kind=ins_spec.kind,
                    radius=ins_spec.shed_radius,
                ))
                free_ends.append(free_end)
            # Conductors toward each neighbour: from a strain string's free end toward the
            # neighbour it points at; from a suspension clamp toward both neighbours.
            starts = free_ends if ins_spec.kind == "strain" else free_ends * 2
            for start, nb in zip(starts, neighbours_local):
                # The same attachment point (across-line offset, height) on the neighbour.
                target = nb + np.array([start[0], 0.0, start[2]])
                conductor_paths.append(_catenary_points(start, target, cond.catenary_parameter,
                                                        cond.modelled_length, cond.segment_length))
            if ins_spec.kind == "strain" and len(free_ends) == 2 and cond.jumper_sag > 0.0:
                a, b = free_ends
                n = max(2, int(math.ceil(np.linalg.norm(b - a) / JUMPER_SEGMENT_LENGTH)))
                t = np.linspace(0.0, 1.0, n + 1)[:, None]
                # Parabolic loop hanging jumper_sag below the chord, pulled slightly
                # outward so it clears the tip.
                loop = a + t * (b - a)
                loop[:, 2] -= 4.0 * cond.jumper_sag * (t[:, 0] * (1.0 - t[:, 0]))
                loop[:, 0] += sx * 0.3 * 4.0 * (t[:, 0] * (1.0 - t[:, 0]))
                conductor_paths.append(loop)

    for k, path in enumerate(conductor_paths):
        info = InstanceInfo(name=f"conductor {k}", kind="conductor", color=CONDUCTOR_COLOR,
                            return_probability=CONDUCTOR_RETURN_PROBABILITY, thin=True)
        local_parts.extend(_polyline(path, cond.radius, CONDUCTOR_ID_BASE + k, info))

    T = np.eye(4)
    T[:3, :3] = R
    structure = Mesh.concatenate(local_parts).transformed(T)
    ground = plane((0.0, 0.0, GROUND_Z), (0.0, 0.0, 1.0), (spec.ground_size, spec.ground_size),
                   instance_id=GROUND_ID, info=GROUND_INFO)
    obstacles = [cylinder(o.start, o.end, o.radius, instance_id=OBSTACLE_ID_BASE + k, segments=12,
                          info=InstanceInfo(name=o.name, kind="obstacle", color=OBSTACLE_COLOR))
                 for k, o in enumerate(spec.obstacles)]
    mesh = Mesh.concatenate([ground, structure, *obstacles])
    # Ground truth as free properties too, so a consumer holding only the mesh has it.
    instances = dict(mesh.instances)
    for truth in truths:
        instances[truth.instance_id] = InstanceInfo(
            name=f"insulator {truth.instance_id}", kind="insulator", color=INSULATOR_COLOR,
            properties={"center": truth.center.tolist(), "axis": truth.axis.tolist(),
                        "length": truth.length, "side": truth.side, "arm": truth.arm})
    mesh = Mesh(mesh.vertices, mesh.triangles, mesh.instance_ids, instances)
    return Tower(spec=spec, mesh=mesh, insulators=tuple(truths))


def load_tower(path: str | Path) -> Tower:
    """Load a scene file (or a built-in scene name such as ``"tower_a"``) and build it."""
    return build_tower(load_scene(path))
