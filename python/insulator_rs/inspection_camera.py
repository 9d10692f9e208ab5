"""The inspection camera: a zoom (or fixed-lens) camera on a 3-axis gimbal, apart from the
detection camera (the paper flew a GoPro on a gimbal beside its Basler detection camera).

Its calibration is taken at the widest zoom, and, for a zoom lens, may be taken at more zoom
steps (the rig's ``zoom_calibrations``): no real lens keeps its principal point and distortion
through its range. At a focal length ``f`` px (the mean of fx and fy):

* between two calibrated steps, every intrinsic (fx, fy, cx, cy, the distortion coefficients) is
  interpolated linearly in ``f`` between the two, and fx and fy are then scaled together so that
  their mean is ``f`` (it is already, to rounding: both are linear in ``f``);
* past the longest calibrated step (or with the widest calibration alone), the nearest step's
  intrinsics with fx and fy scaled by ``f / f_step`` about the same principal point and the same
  distortion coefficients: a zoom lens keeps its optical centre within a few pixels and its
  distortion shrinks as it zooms in, so keeping the wider step's coefficients errs on the side of
  more distortion (the simulator's lens has none).

The gimbal stabilises roll and pitch (the camera stays level whatever the airframe's tilt), is
aimed in pitch and in yaw relative to the body heading, within :class:`GimbalLimits`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from insulator_rs._core import CameraModel

#: A focal length (px) asked of a zoom lens may stray this far (relative) outside its range and
#: be clamped silently: rounding, not a wish the lens cannot meet.
FOCAL_TOLERANCE = 1e-9


@dataclass(frozen=True)
class GimbalLimits:
    """The gimbal's range (rad): ``pitch`` (down negative) and ``yaw`` (relative to the body
    heading, counter-clockwise seen from above), each (min, max)."""

    pitch: tuple[float, float] = (-math.pi / 2, math.pi / 2)
    yaw: tuple[float, float] = (0.0, 0.0)

    def clamp(self, pitch: float, yaw: float) -> tuple[float, float]:
        """``pitch``/``yaw`` (rad) brought inside the limits."""
        return (min(max(pitch, self.pitch[0]), self.pitch[1]), min(max(yaw, self.yaw[0]), self.yaw[1]))


class GimbalRoute:
    """Where a MAVLink payload's gimbal is aimed: ``MANAGER`` = through the autopilot's gimbal
    manager (PX4 with MNT_MODE_IN = 4, MNT_MODE_OUT = 2), ``DEVICE`` = the gimbal device itself
    (no autopilot manages it)."""

    MANAGER = "manager"
    DEVICE = "device"
    ALL = (MANAGER, DEVICE)


@dataclass(frozen=True)
class PayloadLink:
    """How the companion reaches the inspection camera when it is a MAVLink gimbal-and-zoom payload
    (the rig's ``[inspection_camera] payload``): ``connection`` (``udpin:HOST:PORT``,
    ``udpout:HOST:PORT``, ``DEVICE:BAUD``), ``gimbal_route`` (:class:`GimbalRoute`), ``system_id``
    (the payload's MAVLink system, None: the first camera HEARTBEAT's)."""

    connection: str
    gimbal_route: str = GimbalRoute.MANAGER
    system_id: int | None = None


@dataclass(frozen=True)
class InspectionCamera:
    """``camera``: full-resolution intrinsics at the widest zoom; ``T_b_c``: the camera at zero
    gimbal angles on a level body (4x4, p_b = T_b_c @ p_c); ``focal_px``: the zoom range (min,
    max) of the mean focal length in px (min == max: a fixed lens); ``gimbal``: its limits;
    ``make``/``model``/``pixel_pitch_um``: what the EXIF says (None where not given);
    ``dedicated``: False when the rig has no ``[inspection_camera]`` and the detection camera
    stands in, fixed lens and pitch-only gimbal, as before there was one."""

    camera: CameraModel
    T_b_c: np.ndarray
    focal_px: tuple[float, float]
    gimbal: GimbalLimits = field(default_factory=GimbalLimits)
    make: str | None = None
    model: str | None = None
    pixel_pitch_um: float | None = None
    dedicated: bool = True
    #: intrinsics calibrated at further zoom steps, longer than ``camera``'s, shortest first
    zoom_steps: tuple[CameraModel, ...] = ()
    #: a MAVLink gimbal-and-zoom payload the live flight photographs through (None: none)
    payload: PayloadLink | None = None

    @property
    def zoom(self) -> bool:
        return self.focal_px[1] > self.focal_px[0]

    def clamp_focal(self, focal_px: float) -> float:
        """``focal_px`` brought inside the zoom range."""
        return min(max(float(focal_px), self.focal_px[0]), self.focal_px[1])

    def at_focal(self, focal_px: float) -> CameraModel:
        """Full-resolution intrinsics at the mean focal length ``focal_px`` (see the module
        docstring); ValueError outside the zoom range."""
        lo, hi = self.focal_px
        if not (math.isfinite(focal_px) and lo * (1 - FOCAL_TOLERANCE) <= focal_px <= hi * (1 + FOCAL_TOLERANCE)):
            raise ValueError(f"focal_px: {focal_px!r} px is outside the zoom range [{lo:.1f}, {hi:.1f}] px")
        return intrinsics_at(self.calibrated_steps(), self.clamp_focal(focal_px))

    def calibrated_steps(self) -> tuple[CameraModel, ...]:
        """Every calibrated zoom step, the widest (``camera``) first."""
        return (self.camera, *self.zoom_steps)

    def focal_length_mm(self, focal_px: float) -> float | None:
        """The focal length in mm (px x pixel pitch), None where the pixel pitch is not given."""
        return None if self.pixel_pitch_um is None else float(focal_px) * self.pixel_pitch_um * 1e-3

    def exif(self, focal_px: float) -> dict[str, object]:
        """The EXIF camera fields of a photo taken at ``focal_px``: make, model, focal length (mm)."""
        return {"make": self.make, "model": self.model, "focal_length_mm": self.focal_length_mm(focal_px)}


def mean_focal(camera: CameraModel) -> float:
    """The mean of fx and fy (px): what a zoom step is known by."""
    return 0.5 * (camera.fx + camera.fy)


def intrinsics_at(steps: tuple[CameraModel, ...], focal_px: float) -> CameraModel:
    """The intrinsics at the mean focal length ``focal_px`` from calibrated zoom ``steps``
    (shortest first, one image size; the module docstring's rule)."""
    focals = [mean_focal(c) for c in steps]
    upper = next((i for i, f in enumerate(focals) if f >= focal_px), len(steps))
    if upper == 0 or upper == len(steps):  # at or past an end: the nearest step scaled
        c = steps[0] if upper == 0 else steps[-1]
        k = focal_px / mean_focal(c)
        return CameraModel(c.fx * k, c.fy * k, c.cx, c.cy, c.width, c.height, dist=[float(d) for d in c.dist])
    a, b = steps[upper - 1], steps[upper]
    t = (focal_px - focals[upper - 1]) / (focals[upper] - focals[upper - 1])

    def lerp(x: float, y: float) -> float:
        return (1.0 - t) * x + t * y

    fx, fy = lerp(a.fx, b.fx), lerp(a.fy, b.fy)
    k = focal_px / (0.5 * (fx + fy))
    da, db = list(a.dist), list(b.dist)
    n = max(len(da), len(db))
    da, db = da + [0.0] * (n - len(da)), db + [0.0] * (n - len(db))
    return CameraModel(fx * k, fy * k, lerp(a.cx, b.cx), lerp(a.cy, b.cy), a.width, a.height,
                       dist=[lerp(x, y) for x, y in zip(da, db)])
