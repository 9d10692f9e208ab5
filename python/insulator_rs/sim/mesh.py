"""The triangle-mesh container every simulated scene is built into.

A :class:`Mesh` is a triangle soup in the world frame W (metres) where every
triangle belongs to one *instance* (an insulator, a tower, a conductor, the
ground...). The ray caster (``insulator_rs._core.RaycastScene``) reports the
instance id of what each ray hits, so the instance id is the ground truth of the
simulated LiDAR and camera. Per-instance metadata (:class:`InstanceInfo`: kind,
colour, LiDAR return probability) lives beside the arrays.

Instance ids are non-negative ``int32``; ``-1`` is reserved for "no hit".
Ids are global: :meth:`Mesh.concatenate` keeps them as they are and refuses two
meshes that give the same id different metadata.

Primitive builders (:func:`box`, :func:`cylinder`, :func:`plane`) return meshes
with outward-facing triangles (counter-clockwise seen from outside).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from insulator_rs._core import RaycastScene

#: Instance id the ray caster reports for a ray that hits nothing.
NO_HIT: int = -1

#: The kinds of instance the simulator knows (free-form strings are refused so a
#: typo cannot silently make an insulator invisible to ground truth).
INSTANCE_KINDS: frozenset[str] = frozenset(
    {"insulator", "tower", "conductor", "ground", "obstacle", "other"}
)


@dataclass(frozen=True)
class InstanceInfo:
    """Metadata of one instance of a scene.

    ``color`` is linear RGB in [0, 1] (the camera's base albedo).
    ``return_probability`` is the probability that a LiDAR return from this
    instance survives before the incidence-angle loss (1 for solid surfaces;
    below 1 for thin objects such as conductors, whose returns a real Mid-360
    loses often). ``thin`` marks wire-like instances (conductors, thin lattice
    members) for the same purpose. ``properties`` holds free ground truth
    (e.g. an insulator's ``center``, ``axis``, ``length``, ``side``).
    """

    name: str
    kind: str = "other"
    color: tuple[float, float, float] = (0.5, 0.5, 0.5)
    return_probability: float = 1.0
    thin: bool = False
    properties: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in INSTANCE_KINDS:
            raise ValueError(f"kind: {self.kind!r} is not one of {sorted(INSTANCE_KINDS)}")
        color = tuple(float(c) for c in self.color)
        if len(color) != 3 or not all(0.0 <= c <= 1.0 for c in color):
            raise ValueError(f"color: expected 3 values in [0, 1], got {self.color!r}")
        object.__setattr__(self, "color", color)
        p = float(self.return_probability)
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"return_probability: expected a value in [0, 1], got {p}")
        object.__setattr__(self, "return_probability", p)


def _as_array(name: str, value: ArrayLike, dtype: type, ndim: int, last: int | None) -> np.ndarray:
    arr = np.ascontiguousarray(value)
    if arr.ndim != ndim or (last is not None and arr.shape[-1] != last):
        want = f"(N, {last})" if ndim == 2 else "(N,)"
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if arr.size and not np.can_cast(arr.dtype, dtype, casting="same_kind") and arr.dtype.kind not in "iu":
        raise TypeError(f"{name}: expected {np.dtype(dtype).name}-compatible values, got {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=dtype)


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh in W with one instance id per triangle.

    Meshes compare (and hash) by identity: element-wise array equality has no
    single truth value, and the cached BVH belongs to one object.

    ``vertices`` (V, 3) float64 in metres; ``triangles`` (T, 3) uint32 vertex
    indices; ``instance_ids`` (T,) int32 (>= 0); ``instances`` maps every id
    used to its :class:`InstanceInfo`.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    instance_ids: np.ndarray
    instances: Mapping[int, InstanceInfo] = field(default_factory=dict)

    def __post_init__(self) -> None:
        verts = _as_array("vertices", self.vertices, np.float64, 2, 3)
        tris_in = np.asarray(self.triangles)
        if tris_in.size and tris_in.dtype.kind not in "iu":
            raise TypeError(f"triangles: expected integer indices, got {tris_in.dtype}")
        if tris_in.size and (tris_in.min() < 0):
            raise ValueError("triangles: negative vertex index")
        tris = _as_array("triangles", tris_in.reshape(-1, 3) if tris_in.size == 0 else tris_in,
                         np.uint32, 2, 3)
        ids_in = np.asarray(self.instance_ids)
        if ids_in.size and ids_in.dtype.kind not in "iu":
            raise TypeError(f"instance_ids: expected integers, got {ids_in.dtype}")
        ids = _as_array("instance_ids", ids_in.reshape(-1), np.int32, 1, None)
        if not np.all(np.isfinite(verts)):
            raise ValueError("vertices: contains NaN or Inf")
        if tris.size and int(tris.max()) >= len(verts):
            raise ValueError(
                f"triangles: vertex index {int(tris.max())} out of range for {len(verts)} vertices"
            )
        if len(ids) != len(tris):
            raise ValueError(
                f"instance_ids: expected one id per triangle ({len(tris)}), got {len(ids)}"
            )
        if ids.size and int(ids.min()) < 0:
            raise ValueError("instance_ids: ids must be >= 0 (-1 is reserved for 'no hit')")
        instances = {int(k): v for k, v in dict(self.instances).items()}
        for key, info in instances.items():
            if not isinstance(info, InstanceInfo):
                raise TypeError(f"instances[{key}]: expected InstanceInfo, got {type(info).__name__}")
        for used in np.unique(ids):
            instances.setdefault(int(used), InstanceInfo(name=f"instance_{int(used)}"))
        object.__setattr__(self, "vertices", verts)
        object.__setattr__(self, "triangles", tris)
        object.__setattr__(self, "instance_ids", ids)
        object.__setattr__(self, "instances", instances)

    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @classmethod
    def empty(cls) -> Mesh:
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.uint32), np.zeros(0, np.int32))

    @classmethod
    def concatenate(cls, meshes: Sequence[Mesh]) -> Mesh:
        """Join meshes into one, keeping their (global) instance ids.

        Raises ``ValueError`` when two meshes give one id different metadata.
        """
        meshes = list(meshes)
        if not meshes:
            return cls.empty()
        instances: dict[int, InstanceInfo] = {}
        for i, mesh in enumerate(meshes):
            if not isinstance(mesh, Mesh):
                raise TypeError(f"meshes[{i}]: expected Mesh, got {type(mesh).__name__}")
            for key, info in mesh.instances.items():
                if key in instances and instances[key] != info:
                    raise ValueError(
                        f"meshes[{i}]: instance id {key} already used by {instances[key].name!r}"
                        f" with different metadata ({info.name!r})"
                    )
                instances[key] = info
        offsets = np.cumsum([0] + [m.n_vertices for m in meshes[:-1]])
        vertices = np.concatenate([m.vertices for m in meshes])
        triangles = np.concatenate(
            [m.triangles.astype(np.int64) + off for m, off in zip(meshes, offsets)]
        )
        if triangles.size and triangles.max() > np.iinfo(np.uint32).max:
            raise ValueError("meshes: too many vertices for uint32 indices")
        ids = np.concatenate([m.instance_ids for m in meshes])
        return cls(vertices, triangles.astype(np.uint32), ids, instances)

    def transformed(self, T: ArrayLike) -> Mesh:
        """This mesh with its vertices mapped by the 4x4 rigid transform ``T``."""
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T: expected a finite 4x4 matrix, got shape {T.shape}")
        verts = self.vertices @ T[:3, :3].T + T[:3, 3]
        return Mesh(verts, self.triangles, self.instance_ids, self.instances)

    def with_instance(self, instance_id: int, info: InstanceInfo) -> Mesh:
        """This mesh with every triangle relabelled as ``instance_id`` described by ``info``."""
        if instance_id < 0:
            raise ValueError(f"instance_id: must be >= 0, got {instance_id}")
        ids = np.full(self.n_triangles, instance_id, np.int32)
        return Mesh(self.vertices, self.triangles, ids, {int(instance_id): info})

    @cached_property
    def raycaster(self) -> RaycastScene:
        """The mesh in the compiled BVH (built once, on first use)."""
        from insulator_rs._core import RaycastScene

        return RaycastScene(self.vertices, self.triangles, self.instance_ids)

    def _per_instance(self, values: dict[int, Any], default: Any, dtype: type) -> np.ndarray:
        size = max(self.instances, default=-1) + 1
        table = np.full((size, *np.shape(default)), default, dtype=dtype)
        for key, value in values.items():
            table[key] = value
        return table

    def albedo_table(self) -> np.ndarray:
        """(max id + 1, 3) float64 linear RGB colour per instance id (grey for unused ids)."""
        return self._per_instance(
            {k: v.color for k, v in self.instances.items()}, (0.5, 0.5, 0.5), np.float64
        )

    def return_probability_table(self) -> np.ndarray:
        """(max id + 1,) float64 LiDAR return probability per instance id (1 for unused ids)."""
        return self._per_instance(
            {k: v.return_probability for k, v in self.instances.items()}, 1.0, np.float64
        )

    def instance_ids_of_kind(self, kind: str) -> list[int]:
        """Sorted ids of the instances of ``kind`` (one of :data:`INSTANCE_KINDS`)."""
        if kind not in INSTANCE_KINDS:
            raise ValueError(f"kind: {kind!r} is not one of {sorted(INSTANCE_KINDS)}")
        return sorted(k for k, v in self.instances.items() if v.kind == kind)

    def enclosing_instance(self, point: ArrayLike) -> int | None:
        """The instance whose closed surface holds ``point`` (W, m), or None if it is outside.

        Six axis rays leave the point; it is inside when at least four of them first
        meet a back face (the meshes are wound outward). A point below an open ground
        plane counts as inside the ground.
        """
        p = _finite_vec("point", point)
        dirs = np.vstack([np.eye(3), -np.eye(3)])
        hits = self.raycaster.cast(np.tile(p, (6, 1)), dirs, np.inf)
        back = (hits.instance_id >= 0) & (np.einsum("ij,ij->i", hits.normal, dirs) > 0)
        up_id = int(hits.instance_id[2])
        if back[2] and self.instances[up_id].kind == "ground":
            return up_id
        if int(back.sum()) < 4:
            return None
        ids, counts = np.unique(hits.instance_id[back], return_counts=True)
        return int(ids[np.argmax(counts)])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (min, max) in W; raises on an empty mesh."""
        if self.n_vertices == 0:
            raise ValueError("mesh: empty mesh has no bounds")
        return self.vertices.min(axis=0), self.vertices.max(axis=0)


def _single(vertices: np.ndarray, triangles: np.ndarray, instance_id: int,
            info: InstanceInfo | None) -> Mesh:
    if instance_id < 0:
        raise ValueError(f"instance_id: must be >= 0, got {instance_id}")
    ids = np.full(len(triangles), instance_id, np.int32)
    return Mesh(vertices, triangles, ids, {instance_id: info} if info is not None else {})


def _finite_vec(name: str, value: ArrayLike, n: int = 3) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: expected {n} finite numbers, got {value!r}")
    return arr


def box(center: ArrayLike, size: ArrayLike, *, instance_id: int,
        info: InstanceInfo | None = None, rotation: ArrayLike | None = None) -> Mesh:
    """An axis-aligned (or ``rotation``-rotated, 3x3) box of full edge lengths ``size`` (m)."""
    c = _finite_vec("center", center)
    s = _finite_vec("size", size)
    if np.any(s <= 0):
        raise ValueError(f"size: edge lengths must be > 0, got {s.tolist()}")
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    local = corners * s
    if rotation is not None:
        R = np.asarray(rotation, dtype=np.float64)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9):
            raise ValueError("rotation: expected a 3x3 rotation matrix")
        local = local @ R.T
    verts = local + c
    # Corner index = 4*ix + 2*iy + iz. Faces wound counter-clockwise from outside.
    quads = [
        (0, 1, 3, 2),  # -x
        (4, 6, 7, 5),  # +x
        (0, 4, 5, 1),  # -y
        (2, 3, 7, 6),  # +y
        (0, 2, 6, 4),  # -z
        (1, 5, 7, 3),  # +z
    ]
    tris = np.array([t for a, b, c_, d in quads for t in ((a, b, c_), (a, c_, d))], np.uint32)
    return _single(verts, tris, instance_id, info)


def _frame_for_axis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``axis`` and to each other (right-handed with it)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    return u, v


def cylinder(p0: ArrayLike, p1: ArrayLike, radius: float, *, instance_id: int,
             info: InstanceInfo | None = None, segments: int = 16,
             radius_end: float | None = None, capped: bool = True) -> Mesh:
    """A faceted cylinder (or frustum when ``radius_end`` differs) from ``p0`` to ``p1``.

    ``radius`` is at ``p0``, ``radius_end`` (default ``radius``) at ``p1``; the
    polygon's vertices lie on the circle (the facets are inside it). A frustum
    with a tiny height makes an insulator shed.
    """
    a = _finite_vec("p0", p0)
    b = _finite_vec("p1", p1)
    length = float(np.linalg.norm(b - a))
    if length <= 0:
        raise ValueError("p1: must differ from p0")
    r0 = float(radius)
    r1 = r0 if radius_end is None else float(radius_end)
    if not (np.isfinite(r0) and r0 > 0):
        raise ValueError(f"radius: must be > 0, got {radius}")
    if not (np.isfinite(r1) and r1 > 0):
        raise ValueError(f"radius_end: must be > 0, got {radius_end}")
    if segments < 3:
        raise ValueError(f"segments: need at least 3, got {segments}")
    axis = (b - a) / length
    u, v = _frame_for_axis(axis)
    ang = 2.0 * np.pi * np.arange(segments) / segments
    ring = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v
    verts = [a + r0 * ring, b + r1 * ring]
    n = segments
    i = np.arange(n)
    j = (i + 1) % n
    side = np.concatenate([np.stack([i, j, n + j], 1), np.stack([i, n + j, n + i], 1)])
    tris = [side]
    if capped:
        verts.append(np.stack([a, b]))
        ca, cb = 2 * n, 2 * n + 1
        tris.append(np.stack([np.full(n, ca), j, i], 1))  # faces -axis
        tris.append(np.stack([np.full(n, cb), n + i, n + j], 1))  # faces +axis
    return _single(np.concatenate(verts), np.concatenate(tris).astype(np.uint32), instance_id, info)


def plane(center: ArrayLike, normal: ArrayLike, size: tuple[float, float], *, instance_id: int,
          info: InstanceInfo | None = None) -> Mesh:
    """A rectangle of ``size`` (m x m) centred on ``center``, facing ``normal`` (two triangles)."""
    c = _finite_vec("center", center)
    nrm = _finite_vec("normal", normal)
    norm = float(np.linalg.norm(nrm))
    if norm == 0:
        raise ValueError("normal: must be non-zero")
    nrm = nrm / norm
    sx, sy = (float(s) for s in size)
    if not (sx > 0 and sy > 0 and np.isfinite(sx) and np.isfinite(sy)):
        raise ValueError(f"size: expected two lengths > 0, got {size!r}")
    if abs(nrm[2]) > 0.9:
        # Horizontal planes keep their edges on W's x and y axes.
        u = np.array([1.0, 0.0, 0.0])
        v = np.cross(nrm, u)
        v /= np.linalg.norm(v)
        u = np.cross(v, nrm)
    else:
        u, v = _frame_for_axis(nrm)
    hu, hv = 0.5 * sx * u, 0.5 * sy * v
    verts = np.stack([c - hu - hv, c + hu - hv, c + hu + hv, c - hu + hv])
    # Counter-clockwise seen from the side the normal points to.
    if np.dot(np.cross(u, v), nrm) > 0:
        tris = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    else:
        tris = np.array([[0, 2, 1], [0, 3, 2]], np.uint32)
    return _single(verts, tris, instance_id, info)
