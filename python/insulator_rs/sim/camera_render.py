"""The simulated camera: ray-cast RGB and instance-id images, and ground-truth boxes.

The lens is the project's :class:`insulator_rs._core.CameraModel` (pinhole plus
OpenCV radial-tangential distortion). Every pixel's ray in the optical frame C
(z forward, x right, y down) is found once per camera by inverting the
distortion at the pixel centre (``cv2.undistortPoints`` with an iteration criterion of 1e-12);
the compiled renderer then casts those rays through the scene from the camera
pose ``T_w_c = T_w_b @ T_b_c``. Pixel centres are at integer coordinates, as in
OpenCV, so a point that ``cv2.projectPoints`` maps to (u, v) lands in pixel
(round(u), round(v)).

Ground-truth boxes come from the visible pixels of each insulator in the
instance-id image, so occlusion is right by construction.

Default camera: the shipped simulator rig's (``insulator_rs/rigs/simulator.toml`` and its
calibration file, read as any real rig is): 1280x960 with a wide lens, fx = fy = 700 px
(about 85 deg across), mild barrel distortion.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike

from insulator_rs._core import CameraModel
from insulator_rs.poses import check_pose
from insulator_rs.rig import simulator_rig
from insulator_rs.sim.mesh import Mesh

#: Fewer visible pixels than this and an insulator gets no ground-truth box.
MIN_BOX_PIXELS = 20
#: Distortion inversion: iterations and convergence of cv2.undistortPoints.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def default_camera_model() -> CameraModel:
    """The simulated camera's lens, from the shipped simulator rig (``rigs/simulator.toml``)."""
    return simulator_rig().camera


def default_T_b_c() -> np.ndarray:
    """Where the simulated camera sits on the body, from the shipped simulator rig (level,
    looking along the body x axis)."""
    return simulator_rig().T_b_c


def check_outside(mesh: Mesh, position: np.ndarray, what: str) -> None:
    """ValueError when a sensor at ``position`` (W) sits inside the scene's geometry."""
    inside = mesh.enclosing_instance(position)
    if inside is not None:
        name = mesh.instances[inside].name
        raise ValueError(
            f"T_w_b: the {what} at {np.round(position, 3).tolist()} m is inside geometry ({name!r})"
        )


@dataclass(frozen=True)
class Lighting:
    """Light, atmosphere and sensor noise of one rendered image.

    Colours are linear RGB; ``sun_direction`` is a unit vector in W from the scene
    toward the sun; ``haze_density`` is the extinction coefficient in 1/m (0.002
    clear, 0.01 hazy, 0.03 foggy); ``noise_sigma`` is the image noise in 8-bit counts.
    """

    sun_direction: tuple[float, float, float] = (0.5, 0.3, 0.81)
    sun_color: tuple[float, float, float] = (1.0, 0.97, 0.9)
    ambient: tuple[float, float, float] = (0.35, 0.38, 0.45)
    sky_zenith: tuple[float, float, float] = (0.25, 0.45, 0.85)
    sky_horizon: tuple[float, float, float] = (0.75, 0.82, 0.92)
    ground_color: tuple[float, float, float] = (0.30, 0.35, 0.22)
    haze_density: float = 0.002
    noise_sigma: float = 2.0
    shadows: bool = True

    @classmethod
    def at_time_of_day(cls, hour: float, *, haze_density: float = 0.002, noise_sigma: float = 2.0,
                       overcast: float = 0.0, sun_azimuth_offset: float = 0.0) -> Lighting:
        """Lighting for local solar time ``hour`` (6 = sunrise, 12 = noon, 18 = sunset).

        The sun rises in the east (+x of W), culminates in the south at 60 deg
        elevation and sets in the west; low sun is dimmer and redder.
        ``overcast`` in [0, 1] moves light from the sun to the ambient sky.
        """
        if not (math.isfinite(hour) and 5.0 <= hour <= 19.0):
            raise ValueError(f"hour: expected a daytime hour in [5, 19], got {hour}")
        if not 0.0 <= overcast <= 1.0:
            raise ValueError(f"overcast: expected a value in [0, 1], got {overcast}")
        phase = math.pi * (hour - 6.0) / 12.0  # 0 at sunrise, pi at sunset
        elevation = max(math.radians(2.0), math.radians(60.0) * math.sin(phase))
        # Azimuth from east (x) counter-clockwise: 0 at sunrise, -pi/2 (south) at noon.
        azimuth = -phase + sun_azimuth_offset
        sun = (math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
               math.sin(elevation))
        # Low sun: less energy, redder (longer path through the atmosphere).
        strength = (1.0 - overcast) * min(1.0, 0.25 + math.sin(elevation))
        warmth = 1.0 - math.sin(elevation)
        sun_color = (strength, strength * (0.95 - 0.25 * warmth), strength * (0.9 - 0.5 * warmth))
        sky = 0.25 + 0.75 * math.sin(elevation) ** 0.5
        ambient_level = 0.3 + 0.4 * overcast
        ambient = (ambient_level * sky, ambient_level * sky * 1.05, ambient_level * sky * 1.2)
        grey = overcast
        zenith = tuple(sky * ((1 - grey) * z + grey * 0.7) for z in (0.25, 0.45, 0.85))
        horizon = tuple(sky * ((1 - grey) * h + grey * 0.8) for h in (0.75, 0.8 - 0.1 * warmth, 0.92 - 0.3 * warmth))
        return cls(sun_direction=sun, sun_color=sun_color, ambient=ambient,
                   sky_zenith=zenith, sky_horizon=horizon,
                   haze_density=haze_density, noise_sigma=noise_sigma)


@dataclass(frozen=True)
class CameraFrame:
    """One rendered image.

    ``rgb`` (H, W, 3) uint8; ``instance_id`` (H, W) int32 (-1 = sky or far ground);
    ``depth`` (H, W) float32, m along each pixel's ray; ``T_w_c`` the camera pose;
    ``boxes`` maps each visible insulator id to its box (x1, y1, x2, y2) in pixels
    (pixel edges: a box around pixel columns a..b spans a - 0.5 .. b + 0.5);
    ``visible_pixels`` maps the same ids to their pixel counts.
    """

    time: float
    rgb: np.ndarray
    instance_id: np.ndarray
    depth: np.ndarray
    T_w_c: np.ndarray
    boxes: dict[int, tuple[float, float, float, float]] = field(default_factory=dict)
    visible_pixels: dict[int, int] = field(default_factory=dict)


def boxes_from_instance_image(instance_id: np.ndarray, ids: list[int], *,
                              min_pixels: int = MIN_BOX_PIXELS
                              ) -> tuple[dict[int, tuple[float, float, float, float]], dict[int, int]]:
    """Tight boxes around the visible pixels of each instance in ``ids``.

    Returns ({id: (x1, y1, x2, y2)}, {id: pixel count}) for the ids with at least
    ``min_pixels`` visible pixels; coordinates are pixel edges (see CameraFrame).
    """
    if instance_id.ndim != 2:
        raise ValueError(f"instance_id: expected a 2-D image, got shape {instance_id.shape}")
    wanted = np.isin(instance_id, np.asarray(ids, dtype=np.int32))
    rows, cols = np.nonzero(wanted)
    labels = instance_id[rows, cols]
    boxes: dict[int, tuple[float, float, float, float]] = {}
    counts: dict[int, int] = {}
    if labels.size == 0:
        return boxes, counts
    order = np.argsort(labels, kind="stable")
    labels, rows, cols = labels[order], rows[order], cols[order]
    uniq, starts, sizes = np.unique(labels, return_index=True, return_counts=True)
    for key, start, size in zip(uniq, starts, sizes):
        if size < min_pixels:
            continue
        r, c = rows[start:start + size], cols[start:start + size]
        boxes[int(key)] = (c.min() - 0.5, r.min() - 0.5, c.max() + 0.5, r.max() + 0.5)
        counts[int(key)] = int(size)
    return boxes, counts


class Camera:
    """A camera with lens ``model`` mounted on the body by ``T_b_c``."""

    def __init__(self, model: CameraModel | None = None, T_b_c: ArrayLike | None = None) -> None:
        self.model = default_camera_model() if model is None else model
        if not isinstance(self.model, CameraModel):
            raise TypeError(f"model: expected insulator_rs.CameraModel, got {type(self.model).__name__}")
        if self.model.width <= 0 or self.model.height <= 0:
            raise ValueError(f"model: image size must be positive, got {self.model.width}x{self.model.height}")
        self.T_b_c = check_pose("T_b_c", default_T_b_c() if T_b_c is None else T_b_c)

    @property
    def rays_c(self) -> np.ndarray:
        """(H*W, 3) float64 unit rays in C through every pixel centre, row-major (read-only,
        shared by the cameras of one lens: see :func:`cached_pixel_rays`)."""
        return cached_pixel_rays(self.model)

    def render(self, mesh: Mesh, T_w_b: ArrayLike, *, lighting: Lighting | None = None,
               seed: int = 0, time: float = 0.0, min_box_pixels: int = MIN_BOX_PIXELS,
               max_range: float = 1000.0) -> CameraFrame:
        """Renders ``mesh`` seen from the body pose ``T_w_b`` (4x4, W from B).

        Raises ValueError when the camera sits inside geometry.
        """
        lighting = Lighting() if lighting is None else lighting
        T_w_c = check_pose("T_w_b", T_w_b) @ self.T_b_c
        check_outside(mesh, T_w_c[:3, 3], "camera")
        rgb, ids, depth = mesh.raycaster.render(
            T_w_c, self.rays_c, self.model.width, self.model.height, mesh.albedo_table(),
            sun_direction=list(lighting.sun_direction), sun_color=list(lighting.sun_color),
            ambient=list(lighting.ambient), sky_zenith=list(lighting.sky_zenith),
            sky_horizon=list(lighting.sky_horizon), ground_color=list(lighting.ground_color),
            haze_density=lighting.haze_density, noise_sigma=lighting.noise_sigma, seed=seed,
            shadows=lighting.shadows, max_range=max_range,
        )
        boxes, counts = boxes_from_instance_image(
            ids, mesh.instance_ids_of_kind("insulator"), min_pixels=min_box_pixels
        )
        return CameraFrame(time=time, rgb=rgb, instance_id=ids, depth=depth, T_w_c=T_w_c,
                           boxes=boxes, visible_pixels=counts)


#: Ray tables kept by :func:`cached_pixel_rays` (a 12 MP table is 288 MB).
RAY_TABLES_KEPT = 2
_ray_tables: dict[tuple[float, ...], np.ndarray] = {}
_ray_tables_lock = threading.Lock()  # the SITL sensor head renders from its own thread


def cached_pixel_rays(model: CameraModel) -> np.ndarray:
    """:func:`pixel_rays` of ``model``, computed once per lens (read-only). The simulator makes a
    ``Camera`` per photo, and the 12 MP table costs 0.75 s of CPU to build."""
    key = (model.width, model.height, model.fx, model.fy, model.cx, model.cy, *model.dist)
    with _ray_tables_lock:
        rays = _ray_tables.get(key)
        if rays is None:
            rays = pixel_rays(model)
            rays.flags.writeable = False
            while len(_ray_tables) >= RAY_TABLES_KEPT:
                del _ray_tables[next(iter(_ray_tables))]
            _ray_tables[key] = rays
        return rays


def pixel_rays(model: CameraModel) -> np.ndarray:
    """(H*W, 3) unit rays in C through the pixel centres, distortion inverted (row-major)."""
    w, h = model.width, model.height
    if not any(model.dist):  # a pinhole: the rays in closed form (12 MP: 5 s less than undistorting)
        # each ray's length from its (x, y) on the grid, not from the (H*W, 3) table: a zoom is a
        # new lens, so a 12 MP table per zoomed photo; this way it costs a third as much
        x = (np.arange(w, dtype=np.float64) - model.cx) / model.fx
        y = (np.arange(h, dtype=np.float64) - model.cy) / model.fy
        inv = 1.0 / np.sqrt(x[None, :] ** 2 + (y ** 2 + 1.0)[:, None])
        grid = np.empty((h, w, 3))
        np.multiply(x[None, :], inv, out=grid[:, :, 0])
        np.multiply(y[:, None], inv, out=grid[:, :, 1])
        grid[:, :, 2] = inv
        return grid.reshape(-1, 3)
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    normalized = cv2.undistortPoints(
        pixels, model.camera_matrix(), np.asarray(model.dist, dtype=np.float64),
        criteria=_UNDISTORT_CRITERIA,
    ).reshape(-1, 2)
    rays = np.column_stack([normalized, np.ones(len(normalized))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)
