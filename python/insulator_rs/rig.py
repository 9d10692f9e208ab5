"""The vehicle's sensor rig: camera calibration and the extrinsics ``T_b_c``, ``T_b_l``.

A rig file (TOML) describes one airframe, so many missions can share it; a mission names
it with ``[vehicle] rig = "<file>"`` (a path relative to the mission file, or the name of a
shipped rig such as ``"simulator"``). The form (see ``rigs/simulator.toml``)::

    [camera]
    calibration = "camera.yaml"   # OpenCV FileStorage, livox_camera_calib / Autoware camera-LiDAR,
                                  # Kalibr camchain or ROS camera_info YAML, relative to this file
    T_b_c = [[...], [...], [...], [0, 0, 0, 1]]   # 4x4 rows: p_b = T_b_c @ p_c; may be left out when
                                                  # the calibration holds the LiDAR-camera extrinsic
    latency_s = 0.045             # optional: stamp minus exposure (s, in [-0.5, 0.5]), measured: the
                                  # arrival latency of frames whose exposure time the source does
                                  # not give (subtracted); `insulator-rs calibrate time-offset FLIGHT`
                                  # measures it against the LiDAR

    [inspection_camera]           # optional: the photo camera on its gimbal (insulator_rs.inspection_camera);
                                  # without it the detection camera takes the photos, as before
    calibration = "zoom.yaml"     # at the widest zoom; 12 MP class (e.g. 4000x3000)
    make = "..."                  # EXIF make/model (1-32 printable ASCII characters)
    model = "..."
    pixel_pitch_um = 1.55         # sensor pixel size (needed with focal_length_mm)
    focal_length_mm = [4.5, 45.0] # the zoom range; or focal_length_px = [min, max]; neither: fixed lens.
                                  # The wide end must be the calibration's focal length (within 5 %)
    zoom_calibrations = ["zoom_12mm.yaml", "zoom_45mm.yaml"]  # optional: calibrated at further zoom
                                  # steps, wide to long; between steps every intrinsic is interpolated
    T_b_c = [[...], ...]          # optional: the camera at zero gimbal angles on a level body
    gimbal_pitch_deg = [-90, 30]  # gimbal limits (degrees; pitch down negative, yaw from the body
    gimbal_yaw_deg = [-30, 30]    # heading, CCW); roll and pitch are stabilised
    payload = "udpin:0.0.0.0:14560"  # optional: the camera and gimbal are a MAVLink payload (Gimbal v2,
                                  # Camera v2) the live flight photographs through; its connection
    payload_gimbal = "manager"    # optional: aim through the autopilot's gimbal manager (PX4
                                  # MNT_MODE_IN = 4, MNT_MODE_OUT = 2), or "device": straight to it
    payload_system = 1            # optional: the payload's MAVLink system id (default: the first
                                  # camera HEARTBEAT's)

    [lidar]
    T_b_l = [[...], [...], [...], [0, 0, 0, 1]]   # 4x4 rows: p_b = T_b_l @ p_l
    fov_deg = [-7.0, 52.0]        # optional: the LiDAR's vertical field of view in its own frame
                                  # (degrees, down, up); the Livox Mid-360's when left out
    latency_s = 0.0               # optional: how long after its last sample a packet reaches us at
                                  # the least (s, in [0, 0.5]); the driver's clock fit maps stamps
                                  # to the earliest arrivals, so this is subtracted. A Mid-360 on
                                  # Ethernet: 0 (under a millisecond); a sensor that sends late at
                                  # a fixed delay (a gateway, our SITL sensor head) states it

The simulator's own defaults (its camera lens, where its camera and Mid-360 sit) come
from the shipped ``simulator`` rig, so the simulated sensors and the perception that reads
them cannot drift apart. Every error is a :class:`~insulator_rs.exceptions.ConfigError`
naming the file and the field.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs._toml import tomllib
from insulator_rs.calibration import load_calibration
from insulator_rs.exceptions import ConfigError
from insulator_rs.inspection_camera import GimbalLimits, GimbalRoute, InspectionCamera, PayloadLink, mean_focal
from insulator_rs.poses import check_pose
from insulator_rs.textfile import read_config_text

RIGS_DIR = Path(__file__).resolve().parent / "rigs"
SIMULATOR_RIG = "simulator"
#: The Livox Mid-360's vertical field of view (degrees from its x-y plane, down and up: Livox's
#: specification), the LiDAR the live driver speaks to.
MID360_VERTICAL_FOV_DEG = (-7.0, 52.0)
#: The fields of ``[inspection_camera]``.
INSPECTION_FIELDS = {"calibration", "make", "model", "pixel_pitch_um", "focal_length_px", "focal_length_mm",
                     "T_b_c", "gimbal_pitch_deg", "gimbal_yaw_deg", "zoom_calibrations", "payload",
                     "payload_gimbal", "payload_system"}
#: The zoom range's wide end and the calibration (taken at the widest zoom) may differ this much
#: (relative): a lens's stated focal length is rounded.
ZOOM_CALIBRATION_TOLERANCE = 0.05
#: The optical frame looking along the body x axis (C's z = B's x, C's x = -B's y, C's y = -B's z):
#: an inspection camera's mount when the rig does not give one.
FORWARD_T_B_C = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
#: The camera latency a rig may state (s, either sign): beyond half a second a stamp is not late, it is wrong.
MAX_CAMERA_LATENCY_S = 0.5
#: The LiDAR latency a rig may state (s, packet arrival minus its last sample; not negative).
MAX_LIDAR_LATENCY_S = 0.5


@dataclass(frozen=True)
class CameraLens:
    """What the photos' EXIF and the GCS's CAMERA_INFORMATION say of the camera: ``make``,
    ``model`` (rig file ``[camera] make``/``model``, at most 32 characters) and
    ``pixel_pitch_um`` (``[camera] pixel_pitch_um``: the sensor's pixel size, which turns the
    calibration's focal length in px into mm); None where the rig does not say."""

    make: str | None = None
    model: str | None = None
    pixel_pitch_um: float | None = None

    def focal_length_mm(self, camera: CameraModel) -> float | None:
        if self.pixel_pitch_um is None:
            return None
        return 0.5 * (camera.fx + camera.fy) * self.pixel_pitch_um * 1e-3


@dataclass(frozen=True)
class SensorRig:
    """A validated rig: ``camera`` (full-resolution intrinsics), ``T_b_c`` and ``T_b_l`` (4x4
    float64 rigid transforms), ``source`` (the file it came from), ``lens`` (make, model, pixel
    pitch of the camera, where the rig gives them), ``camera_latency_s`` (``[camera] latency_s``:
    the frame stamp minus its exposure time, s; 0 where the rig does not say), which the live
    camera subtracts from the arrival of a frame whose exposure time it does not know;
    ``lidar_latency_s`` (``[lidar] latency_s``: the least delay from a LiDAR packet's last sample
    to its arrival, s; 0 where the rig does not say), which the live LiDAR driver subtracts from
    its map of the sensor's clock onto the host's."""

    source: str
    camera: CameraModel
    T_b_c: np.ndarray
    T_b_l: np.ndarray
    lens: CameraLens = CameraLens()
    camera_latency_s: float = 0.0
    lidar_fov_deg: tuple[float, float] = MID360_VERTICAL_FOV_DEG
    inspection: InspectionCamera | None = None
    lidar_latency_s: float = 0.0

    def inspection_camera(self) -> InspectionCamera:
        """The camera that takes the inspection photos: the rig's ``[inspection_camera]``, or,
        for a rig without one, the detection camera standing in (fixed lens, the gimbal pitch
        only, not dedicated) as every rig flew before there was one."""
        if self.inspection is not None:
            return self.inspection
        f = 0.5 * (self.camera.fx + self.camera.fy)
        return InspectionCamera(self.camera, self.T_b_c.copy(), (f, f), GimbalLimits(), self.lens.make,
                                self.lens.model, self.lens.pixel_pitch_um, dedicated=False)

    def vertical_view(self) -> tuple[float, float]:
        """Elevations (rad, down < up) that the camera and the LiDAR both see straight ahead of a
        level body (along its x axis): localization needs a box and its points at once.

        The camera's are the pinhole angles of the image's top and bottom rows at the principal
        column; a barrel lens sees a little more there, so this errs on the side of less. The
        LiDAR's are its field of view's two edges in its own x direction, carried through
        ``T_b_l`` (a pitched mount moves them)."""
        cam = self.camera
        rows = ((-0.5 - cam.cy) / cam.fy, (cam.height - 0.5 - cam.cy) / cam.fy)  # image y down
        cam_el = [_elevation(self.T_b_c[:3, :3] @ np.array([0.0, y, 1.0])) for y in rows]
        lidar_el = [_elevation(self.T_b_l[:3, :3] @ np.array([np.cos(e), 0.0, np.sin(e)]))
                    for e in np.radians(self.lidar_fov_deg)]
        down = max(min(cam_el), min(lidar_el))
        up = min(max(cam_el), max(lidar_el))
        if not down < up:
            raise ConfigError(f"{self.source}: camera.T_b_c, lidar.T_b_l: the camera and the LiDAR "
                              f"share no elevation straight ahead (camera {np.degrees(cam_el).round(1)}, "
                              f"LiDAR {np.degrees(lidar_el).round(1)} deg)")
        return float(down), float(up)

    def exif_camera(self) -> dict[str, Any]:
        """The photos' EXIF camera fields: make, model and the focal length in mm (from the
        full-resolution calibration and the pixel pitch; None where the rig does not say)."""
        return {"make": self.lens.make, "model": self.lens.model,
                "focal_length_mm": self.lens.focal_length_mm(self.camera)}


def _elevation(direction: np.ndarray) -> float:
    """The angle (rad) of a body-frame direction above the body's x-y plane."""
    return float(np.arctan2(direction[2], np.hypot(direction[0], direction[1])))


def resolve_rig(name: str, relative_to: Path | None = None) -> Path:
    """The rig file ``name`` stands for: a shipped rig's name, or a path (relative to
    ``relative_to``, the mission file's folder, when not absolute)."""
    shipped = RIGS_DIR / f"{name}.toml"
    if "/" not in name and "\\" not in name and not name.endswith(".toml") and shipped.is_file():
        return shipped
    path = Path(name).expanduser()
    if not path.is_absolute() and relative_to is not None:
        path = relative_to / path
    return path


def _matrix(source: str, table: dict[str, Any], prefix: str, key: str) -> np.ndarray:
    field = f"{prefix}.{key}"
    if key not in table:
        raise ConfigError(f"{source}: {field}: missing (a 4x4 matrix, rows)")
    try:
        value = np.array(table[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: {field}: expected 4 rows of 4 numbers ({exc})") from exc
    try:
        return check_pose(field, value)
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from exc


def _table(source: str, data: dict[str, Any], key: str, allowed: set[str]) -> dict[str, Any]:
    table = data.get(key)
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: {key}: missing table" if table is None
                          else f"{source}: {key}: expected a table, got {type(table).__name__}")
    extra = sorted(set(table) - allowed)
    if extra:
        raise ConfigError(f"{source}: {key}.{extra[0]}: unknown field (allowed: {', '.join(sorted(allowed))})")
    return table


def load_rig(path: str | Path) -> SensorRig:
    """Read and validate a rig file (see the module docstring)."""
    p = Path(path)
    source = str(p)
    text = read_config_text(p, f"{source}: <file>")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: <file>: cannot parse: {exc}") from exc
    extra = sorted(set(data) - {"camera", "lidar", "inspection_camera"})
    if extra:
        raise ConfigError(f"{source}: {extra[0]}: unknown field (allowed: camera, inspection_camera, lidar)")
    cam_t = _table(source, data, "camera", {"calibration", "T_b_c", "make", "model", "pixel_pitch_um", "latency_s"})
    lidar_t = _table(source, data, "lidar", {"T_b_l", "fov_deg", "latency_s"})
    cal = _calibration(source, p, cam_t, "camera")
    T_b_l = _matrix(source, lidar_t, "lidar", "T_b_l")
    if "T_b_c" in cam_t or cal.T_c_l is None:
        T_b_c = _matrix(source, cam_t, "camera", "T_b_c")
    else:  # the camera-LiDAR calibration's extrinsic places the camera on the body through the LiDAR
        T_b_c = T_b_l @ np.linalg.inv(cal.T_c_l)
    inspection = None
    if "inspection_camera" in data:
        inspection = _inspection_camera(source, p, _table(source, data, "inspection_camera", INSPECTION_FIELDS))
    return SensorRig(source, cal.camera, T_b_c, T_b_l, _lens(source, cam_t), _latency(source, cam_t),
                     _lidar_fov(source, lidar_t), inspection, _lidar_latency(source, lidar_t))


def _calibration(source: str, p: Path, table: dict[str, Any], prefix: str) -> Any:
    """The calibration file named by ``<prefix>.calibration`` (relative to the rig file)."""
    calibration = table.get("calibration")
    if not isinstance(calibration, str) or not calibration:
        raise ConfigError(f"{source}: {prefix}.calibration: expected the calibration file's path, "
                          f"got {calibration!r}")
    cal_path = Path(calibration).expanduser()
    if not cal_path.is_absolute():
        cal_path = p.resolve().parent / cal_path
    try:
        return load_calibration(cal_path)
    except (ConfigError, OSError) as exc:  # a bad calibration, or none at that path
        raise ConfigError(f"{source}: {prefix}.calibration: {exc}") from exc


def _range(source: str, table: dict[str, Any], key: str, lo: float, hi: float, unit: str,
           default: tuple[float, float] | None) -> tuple[float, float] | None:
    """``[inspection_camera] <key>``: [min, max] numbers with lo <= min <= max <= hi."""
    if key not in table:
        return default
    value = table[key]
    ok = (isinstance(value, list) and len(value) == 2
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
          and lo <= float(value[0]) <= float(value[1]) <= hi)
    if not ok:
        raise ConfigError(f"{source}: inspection_camera.{key}: expected [min, max] {unit} with "
                          f"{lo:g} <= min <= max <= {hi:g}, got {value!r}")
    return float(value[0]), float(value[1])


def _inspection_camera(source: str, p: Path, t: dict[str, Any]) -> InspectionCamera:
    """``[inspection_camera]`` (module docstring): its calibration at the widest zoom, the zoom
    range (``focal_length_px``, or ``focal_length_mm`` with ``pixel_pitch_um``; neither: a fixed
    lens), whose wide end must be the calibration's focal length (within
    :data:`ZOOM_CALIBRATION_TOLERANCE`), the mount ``T_b_c`` (the detection camera's axes at the
    body origin when left out) and the gimbal's pitch and yaw limits (degrees)."""
    cal = _calibration(source, p, t, "inspection_camera")
    cam = cal.camera
    lens = _lens(source, t, "inspection_camera")
    f_cal = 0.5 * (cam.fx + cam.fy)
    if "focal_length_px" in t and "focal_length_mm" in t:
        raise ConfigError(f"{source}: inspection_camera.focal_length_mm: give focal_length_px or "
                          f"focal_length_mm, not both")
    focal = _range(source, t, "focal_length_px", 1.0, 1e6, "px", None)
    key = "focal_length_px"
    if "focal_length_mm" in t:
        key = "focal_length_mm"
        mm = _range(source, t, key, 0.1, 2000.0, "mm", None)
        if lens.pixel_pitch_um is None:
            raise ConfigError(f"{source}: inspection_camera.pixel_pitch_um: missing (focal_length_mm "
                              f"needs the pixel pitch to give px)")
        assert mm is not None
        focal = (mm[0] / (lens.pixel_pitch_um * 1e-3), mm[1] / (lens.pixel_pitch_um * 1e-3))
    if focal is None:
        focal = (f_cal, f_cal)  # a fixed lens
    elif abs(focal[0] - f_cal) > ZOOM_CALIBRATION_TOLERANCE * f_cal:
        raise ConfigError(f"{source}: inspection_camera.{key}: the widest end ({focal[0]:.1f} px) is not "
                          f"the calibration's focal length ({f_cal:.1f} px): calibrate at the widest zoom")
    else:
        focal = (f_cal, focal[1])
    T_b_c = _matrix(source, t, "inspection_camera", "T_b_c") if "T_b_c" in t else FORWARD_T_B_C.copy()
    pitch = _range(source, t, "gimbal_pitch_deg", -180.0, 180.0, "degrees", (-90.0, 30.0))
    yaw = _range(source, t, "gimbal_yaw_deg", -180.0, 180.0, "degrees", (0.0, 0.0))
    assert pitch is not None and yaw is not None
    gimbal = GimbalLimits((math.radians(pitch[0]), math.radians(pitch[1])),
                          (math.radians(yaw[0]), math.radians(yaw[1])))
    steps = _zoom_steps(source, p, t, cam, focal)
    return InspectionCamera(cam, T_b_c, focal, gimbal, lens.make, lens.model, lens.pixel_pitch_um,
                            zoom_steps=steps, payload=_payload_link(source, t))


def _payload_link(source: str, t: dict[str, Any]) -> PayloadLink | None:
    """``[inspection_camera] payload`` (a MAVLink connection to a gimbal-and-zoom payload),
    ``payload_gimbal`` ("manager": through the autopilot's gimbal manager, the default; "device":
    straight to the gimbal) and ``payload_system`` (its system id; default: the first camera
    HEARTBEAT's). The live flight photographs through it."""
    if "payload" not in t:
        extra = sorted({"payload_gimbal", "payload_system"} & set(t))
        if extra:
            raise ConfigError(f"{source}: inspection_camera.{extra[0]}: needs inspection_camera.payload "
                              f"(the payload's MAVLink connection)")
        return None
    connection = t["payload"]
    if not isinstance(connection, str) or not connection.strip():
        raise ConfigError(f"{source}: inspection_camera.payload: expected a MAVLink connection "
                          f"(udpin:HOST:PORT, udpout:HOST:PORT or DEVICE:BAUD), got {connection!r}")
    route = t.get("payload_gimbal", GimbalRoute.MANAGER)
    if route not in GimbalRoute.ALL:
        raise ConfigError(f"{source}: inspection_camera.payload_gimbal: expected one of "
                          f"{', '.join(GimbalRoute.ALL)}, got {route!r}")
    system = t.get("payload_system")
    if system is not None and not (isinstance(system, int) and not isinstance(system, bool) and 1 <= system <= 255):
        raise ConfigError(f"{source}: inspection_camera.payload_system: expected a MAVLink system id in "
                          f"[1, 255], got {system!r}")
    return PayloadLink(connection.strip(), route, system)


def _zoom_steps(source: str, p: Path, t: dict[str, Any], widest: CameraModel,
                focal: tuple[float, float]) -> tuple[CameraModel, ...]:
    """``[inspection_camera] zoom_calibrations``: calibration files (paths relative to the rig
    file) taken at further zoom steps, each of the widest calibration's image size, their focal
    lengths rising from past the widest's to at most the zoom range's long end."""
    if "zoom_calibrations" not in t:
        return ()
    key = "inspection_camera.zoom_calibrations"
    files = t["zoom_calibrations"]
    if not (isinstance(files, list) and files and all(isinstance(f, str) and f for f in files)):
        raise ConfigError(f"{source}: {key}: expected a list of calibration files, got {files!r}")
    steps: list[CameraModel] = []
    previous = mean_focal(widest)
    for i, name in enumerate(files):
        cam = _calibration(source, p, {"calibration": name}, f"{key}[{i}]").camera
        f = mean_focal(cam)
        if (cam.width, cam.height) != (widest.width, widest.height):
            raise ConfigError(f"{source}: {key}[{i}]: {name}: {cam.width}x{cam.height} px, the widest "
                              f"calibration's is {widest.width}x{widest.height} px")
        if not f > previous:
            raise ConfigError(f"{source}: {key}[{i}]: {name}: focal length {f:.1f} px is not longer than "
                              f"the step before ({previous:.1f} px): list the steps from wide to long")
        if f > focal[1] * (1 + ZOOM_CALIBRATION_TOLERANCE):
            raise ConfigError(f"{source}: {key}[{i}]: {name}: focal length {f:.1f} px is past the zoom "
                              f"range's long end ({focal[1]:.1f} px)")
        steps.append(cam)
        previous = f
    return tuple(steps)


def _lidar_fov(source: str, lidar_t: dict[str, Any]) -> tuple[float, float]:
    """``[lidar] fov_deg``: two numbers, -90 <= down < up <= 90; the Mid-360's when left out."""
    value = lidar_t.get("fov_deg", list(MID360_VERTICAL_FOV_DEG))
    ok = (isinstance(value, list) and len(value) == 2
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
          and -90.0 <= float(value[0]) < float(value[1]) <= 90.0)
    if not ok:
        raise ConfigError(f"{source}: lidar.fov_deg: expected [down, up] degrees with "
                          f"-90 <= down < up <= 90, got {value!r}")
    return float(value[0]), float(value[1])



def _latency(source: str, cam_t: dict[str, Any]) -> float:
    """``[camera] latency_s``: a number in [-MAX_CAMERA_LATENCY_S, MAX_CAMERA_LATENCY_S] s, 0 when
    left out (either sign: measured against the LiDAR's clock, it carries that clock's error too)."""
    value = cam_t.get("latency_s", 0.0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not abs(float(value)) <= MAX_CAMERA_LATENCY_S:
        raise ConfigError(f"{source}: camera.latency_s: expected a number in [-{MAX_CAMERA_LATENCY_S:g}, "
                          f"{MAX_CAMERA_LATENCY_S:g}] s (stamp minus exposure, measured), got {value!r}")
    return float(value)


def _lidar_latency(source: str, lidar_t: dict[str, Any]) -> float:
    """``[lidar] latency_s``: a number in [0, MAX_LIDAR_LATENCY_S] s, 0 when left out."""
    value = lidar_t.get("latency_s", 0.0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= float(value) <= MAX_LIDAR_LATENCY_S:
        raise ConfigError(f"{source}: lidar.latency_s: expected a number in [0, {MAX_LIDAR_LATENCY_S:g}] s "
                          f"(a packet's arrival minus its last sample, at the least), got {value!r}")
    return float(value)


def _lens(source: str, cam_t: dict[str, Any], prefix: str = "camera") -> CameraLens:
    """``[camera] make``, ``model`` (printable ASCII, 1-32 characters: EXIF and MAVLink's
    CAMERA_INFORMATION hold 32 bytes) and ``pixel_pitch_um`` (0.5-50 um: phone to machine-vision
    sensors)."""
    names: dict[str, str | None] = {}
    for key in ("make", "model"):
        v = cam_t.get(key)
        if v is not None and not (isinstance(v, str) and 1 <= len(v) <= 32 and all(32 <= ord(c) < 127 for c in v)):
            raise ConfigError(f"{source}: {prefix}.{key}: expected 1-32 printable ASCII characters, got {v!r}")
        names[key] = v
    pitch = cam_t.get("pixel_pitch_um")
    if pitch is not None:
        if isinstance(pitch, bool) or not isinstance(pitch, (int, float)) or not (0.5 <= float(pitch) <= 50.0):
            raise ConfigError(f"{source}: {prefix}.pixel_pitch_um: expected a number in [0.5, 50] um, got {pitch!r}")
        pitch = float(pitch)
    return CameraLens(names["make"], names["model"], pitch)


@functools.lru_cache(maxsize=1)
def _simulator_rig() -> SensorRig:
    return load_rig(RIGS_DIR / f"{SIMULATOR_RIG}.toml")


def simulator_rig() -> SensorRig:
    """The shipped rig of the simulated airframe (arrays copied: callers may modify them)."""
    rig = _simulator_rig()
    inspection = None if rig.inspection is None else replace(rig.inspection, T_b_c=rig.inspection.T_b_c.copy())
    return SensorRig(rig.source, rig.camera, rig.T_b_c.copy(), rig.T_b_l.copy(), rig.lens, rig.camera_latency_s,
                     rig.lidar_fov_deg, inspection, rig.lidar_latency_s)


def scaled_camera(model: CameraModel, scale: float) -> CameraModel:
    """``model`` for the same lens at ``scale`` times the resolution (a binned or resized image).

    Pixel centres sit at integer coordinates (OpenCV), so a pixel edge at -0.5 stays at -0.5:
    ``u' = (u + 0.5) * s - 0.5`` for the principal point, ``f' = f * s``; distortion acts on
    normalized coordinates and is unchanged. The per-axis factor is the rounded size's
    (``w' / w``), so the image still spans the same field of view."""
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale: must be a finite number > 0, got {scale!r}")
    w, h = max(16, int(round(model.width * scale))), max(12, int(round(model.height * scale)))
    sx, sy = w / model.width, h / model.height
    return CameraModel(model.fx * sx, model.fy * sy, (model.cx + 0.5) * sx - 0.5, (model.cy + 0.5) * sy - 0.5,
                       w, h, dist=[float(k) for k in model.dist])


def write_camera_latency(path: str | Path, latency_s: float) -> SensorRig:
    """Set ``[camera] latency_s`` in the rig file at ``path`` (the line replaced, or added under
    ``[camera]``; comments and the rest kept), then read the file back as a rig; on any error
    the file is left as it was (ConfigError names the file and the field)."""
    p = Path(path)
    text = read_config_text(p, f"{p}: <file>")
    if not (np.isfinite(latency_s) and abs(latency_s) <= MAX_CAMERA_LATENCY_S):
        raise ConfigError(f"{p}: camera.latency_s: {latency_s!r} s is outside "
                          f"[-{MAX_CAMERA_LATENCY_S:g}, {MAX_CAMERA_LATENCY_S:g}]")
    lines = text.splitlines(keepends=True)
    line = f"latency_s = {latency_s:.4f}  # s: frame stamp minus exposure (insulator-rs calibrate time-offset)\n"
    section = None
    at = None
    for i, raw in enumerate(lines):
        stripped = raw.strip()
        if stripped.startswith("["):
            section = stripped.split("#", 1)[0].strip()
            if section == "[camera]":
                at = i + 1
        elif section == "[camera]" and stripped.split("=", 1)[0].strip() == "latency_s":
            lines[i] = line
            break
    else:
        if at is None:
            raise ConfigError(f"{p}: camera: missing table (not a rig file)")
        lines.insert(at, line)
    p.write_text("".join(lines), encoding="utf-8")
    try:
        return load_rig(p)
    except ConfigError:
        p.write_text(text, encoding="utf-8")
        raise
