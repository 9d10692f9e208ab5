"""Type stubs of the compiled extension ``insulator_rs._core`` (Rust, pyo3).

Checked against the built module by ``python -m mypy.stubtest insulator_rs._core``.
Frames and units: see the docstrings; metres, pixels, radians.
"""

from typing import Any, Final, final, overload

import numpy as np
from numpy.typing import NDArray

from insulator_rs.exceptions import AmbiguousLocalizationError as AmbiguousLocalizationError
from insulator_rs.exceptions import LocalizationError as LocalizationError

# A point cloud: (N, 3) float32 or float64, any strides.
_Points = NDArray[np.float32] | NDArray[np.float64]

__all__ = [
    "AmbiguousLocalizationError",
    "CameraModel",
    "InsulatorString",
    "LineFit",
    "Localization",
    "LivoxScan",
    "LivoxScanAssembler",
    "LivoxReceiver",
    "LocalizationError",
    "MAX_STRING_POINTS",
    "NEAR_LIMIT",
    "SCALE_TOLERANCE",
    "NOISE",
    "Pca",
    "RaycastHits",
    "RaycastScene",
    "chain_transforms",
    "dbscan",
    "deskew",
    "deskew_points_in_boxes",
    "find_insulator_strings",
    "find_insulator_strings_defaults",
    "localize",
    "livox_decode_command",
    "livox_discovery_request",
    "livox_encode_command",
    "livox_host_config_request",
    "livox_parse_config_ack",
    "livox_parse_discovery_ack",
    "livox_parse_header",
    "livox_work_mode_request",
    "localize_bounded",
    "localize_defaults",
    "localize_methods",
    "pca",
    "points_in_boxes",
    "project_points",
    "ransac_line",
    "resize_linear",
]

NEAR_LIMIT: Final[float]
SCALE_TOLERANCE: Final[float]
NOISE: Final[int]
MAX_STRING_POINTS: Final[int]

@final
class CameraModel:
    """Pinhole camera with OpenCV (k1, k2, p1, p2, k3) distortion; pixels."""

    def __new__(
        cls,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        width: int,
        height: int,
        dist: tuple[float, float, float, float, float] | list[float] | None = None,
    ) -> CameraModel: ...
    @property
    def fx(self) -> float: ...
    @property
    def fy(self) -> float: ...
    @property
    def cx(self) -> float: ...
    @property
    def cy(self) -> float: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def dist(self) -> tuple[float, float, float, float, float]: ...
    def camera_matrix(self) -> NDArray[np.float64]: ...
    def __eq__(self, value: object, /) -> bool: ...
    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]: ...

@final
class LineFit:
    """RANSAC line: inlier centroid, unit direction, inlier indices, iterations run."""

    @property
    def point(self) -> NDArray[np.float64]: ...
    @property
    def direction(self) -> NDArray[np.float64]: ...
    @property
    def inliers(self) -> NDArray[np.int64]: ...
    @property
    def iterations(self) -> int: ...

@final
class Pca:
    """Mean, descending eigenvalues, eigenvectors as columns, points used."""

    @property
    def mean(self) -> NDArray[np.float64]: ...
    @property
    def eigenvalues(self) -> NDArray[np.float64]: ...
    @property
    def eigenvectors(self) -> NDArray[np.float64]: ...
    @property
    def n_points(self) -> int: ...

@final
class Localization:
    """Insulator centre and unit axis in the body frame B, by any method (the image fields are
    the bounded method's: 0, None and 0 for the paper's four)."""

    @property
    def center(self) -> NDArray[np.float64]: ...
    @property
    def direction(self) -> NDArray[np.float64]: ...
    @property
    def n_points(self) -> int: ...
    @property
    def n_clusters(self) -> int: ...
    @property
    def n_nonfinite(self) -> int: ...
    @property
    def method(self) -> str: ...
    @property
    def ends_from_image(self) -> int: ...
    @property
    def length(self) -> float | None: ...
    @property
    def views_used(self) -> int: ...

def chain_transforms(T_c_b: Any, T_b_l: Any) -> NDArray[np.float64]: ...
def project_points(
    points_l: _Points, T_c_l: Any, cam: CameraModel
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]: ...
def points_in_boxes(
    points_l: _Points, T_c_l: Any, cam: CameraModel, boxes: Any
) -> list[NDArray[np.int64]]: ...
def deskew(
    points_l: _Points, times: Any, pose_times: Any, poses: Any, t_ref: float, T_b_l: Any
) -> NDArray[np.float64]: ...
def deskew_points_in_boxes(
    points_l: _Points,
    times: Any,
    pose_times: Any,
    poses: Any,
    t_ref: float,
    T_b_l: Any,
    T_c_l: Any,
    cam: CameraModel,
    boxes: Any,
) -> tuple[NDArray[np.float64], list[NDArray[np.int64]]]: ...
def dbscan(points: _Points, eps: float, min_points: int) -> NDArray[np.int32]: ...
def ransac_line(
    points: _Points,
    threshold: float,
    *,
    max_iterations: int = ...,
    confidence: float = ...,
    seed: int = ...,
) -> LineFit: ...
def pca(points: _Points) -> Pca: ...
def resize_linear(image: NDArray[np.uint8], width: int, height: int) -> NDArray[np.uint8]: ...
# ``method``: a name of ``insulator_rs.LocalizationMethod`` (a str enum; any other string
# raises ValueError). ``boxes``, ``T_b_c``, ``cam`` and ``insulator_length`` only for "bounded".
def localize(
    points_b: _Points,
    method: str = ...,
    *,
    boxes: Any = None,
    T_b_c: Any = None,
    cam: CameraModel | None = None,
    insulator_length: float | None = None,
    border_margin: float = ...,
    max_extent: float = ...,
    eps: float = ...,
    min_points: int = ...,
    tau: float = ...,
    ransac_threshold: float = ...,
    max_iterations: int = ...,
    confidence: float = ...,
    seed: int = ...,
) -> Localization: ...
def localize_bounded(points_b: _Points, boxes: Any, T_b_c: Any, cam: CameraModel, **tuning: Any) -> Localization: ...
@overload
def localize_defaults(method: None = None) -> dict[str, float | int]: ...
@overload
def localize_defaults(method: str) -> dict[str, float | int | None]: ...
def localize_methods() -> list[str]: ...
@final
class InsulatorString:
    """An insulator string found by ``find_insulator_strings`` (m, rad; the cloud's frame)."""

    @property
    def center(self) -> NDArray[np.float64]: ...
    @property
    def axis(self) -> NDArray[np.float64]: ...
    @property
    def length(self) -> float: ...
    @property
    def radius(self) -> float: ...
    @property
    def n_points(self) -> int: ...
    @property
    def score(self) -> float: ...
    @property
    def elevation(self) -> float: ...

def find_insulator_strings(
    points: _Points,
    *,
    up: tuple[float, float, float] | NDArray[np.float64] = (0.0, 0.0, 1.0),
    voxel_size: float = ...,
    min_length: float = ...,
    max_length: float = ...,
    min_score: float = ...,
) -> list[InsulatorString]: ...
def find_insulator_strings_defaults() -> list[tuple[str, float]]: ...

# --- scene ray casting (src/raycast.rs, the simulator's LiDAR and camera) ---

@final
class RaycastHits:
    """Per-ray hits: distance (inf on a miss), instance id and triangle (-1), normal."""

    @property
    def distance(self) -> NDArray[np.float64]: ...
    @property
    def instance_id(self) -> NDArray[np.int32]: ...
    @property
    def triangle(self) -> NDArray[np.int64]: ...
    @property
    def normal(self) -> NDArray[np.float64]: ...
    def __len__(self) -> int: ...

@final
class RaycastScene:
    """A static triangle scene in the world frame W (BVH) for ray casting and rendering."""

    def __new__(cls, vertices: Any, triangles: Any, instance_ids: Any) -> RaycastScene: ...
    @property
    def n_triangles(self) -> int: ...
    def cast(self, origins: Any, directions: Any, max_range: float) -> RaycastHits: ...
    def render(
        self,
        T_w_c: Any,
        rays_c: Any,
        width: int,
        height: int,
        albedo: Any,
        *,
        sun_direction: tuple[float, float, float] | list[float] = ...,
        sun_color: tuple[float, float, float] | list[float] = ...,
        ambient: tuple[float, float, float] | list[float] = ...,
        sky_zenith: tuple[float, float, float] | list[float] = ...,
        sky_horizon: tuple[float, float, float] | list[float] = ...,
        ground_color: tuple[float, float, float] | list[float] = ...,
        ground_height: float = 0.0,
        haze_density: float = 0.0,
        noise_sigma: float = 0.0,
        seed: int = ...,
        shadows: bool = True,
        max_range: float = 1000.0,
    ) -> tuple[NDArray[np.uint8], NDArray[np.int32], NDArray[np.float32]]: ...

# --- Livox Mid-360 (SDK2 protocol): crates/livox_mid360 -------------------------------

@final
class LivoxScan:
    """One 10 Hz scan in the sensor clock: points (N, 3) float32 in the LiDAR frame (m),
    per-point times_ns (N,) uint64, reflectivity and tag (N,) uint8; the window
    [start_ns, end_ns); packets that contributed; partial if the window was not covered."""

    @property
    def points(self) -> NDArray[np.float32]: ...
    @property
    def times_ns(self) -> NDArray[np.uint64]: ...
    @property
    def reflectivity(self) -> NDArray[np.uint8]: ...
    @property
    def tag(self) -> NDArray[np.uint8]: ...
    @property
    def start_ns(self) -> int: ...
    @property
    def end_ns(self) -> int: ...
    @property
    def packets(self) -> int: ...
    @property
    def partial(self) -> bool: ...
    def __len__(self) -> int: ...

@final
class LivoxScanAssembler:
    """Point-cloud / IMU datagrams in, 10 Hz scans out; every fault counted (``stats``)."""

    def __new__(
        cls,
        *,
        frame_period_s: float = 0.1,
        reorder_grace_s: float = 0.005,
        resync_gap_s: float = 1.0,
        keep_zero_points: bool = False,
        max_queued_scans: int = 16,
    ) -> LivoxScanAssembler: ...
    def push(self, datagram: bytes) -> str: ...
    def pop_scan(self) -> LivoxScan | None: ...
    def drain_imu(self) -> tuple[NDArray[np.uint64], NDArray[np.float32], NDArray[np.float32]]: ...
    def flush(self) -> None: ...
    @property
    def pending_scans(self) -> int: ...
    def stats(self) -> dict[str, int]: ...

@final
class LivoxReceiver:
    """A Mid-360 read, stamped on arrival, filtered and assembled by Rust threads (no GIL)."""

    def __new__(
        cls,
        fds: list[int],
        *,
        lidar_ip: str | None = None,
        accepting: bool = True,
        frame_period_s: float = 0.1,
        reorder_grace_s: float = 0.005,
        resync_gap_s: float = 1.0,
        keep_zero_points: bool = False,
        max_queued_scans: int = 64,
    ) -> LivoxReceiver: ...
    def take(
        self, timeout_s: float
    ) -> tuple[
        list[LivoxScan],
        tuple[NDArray[np.uint64], NDArray[np.float32], NDArray[np.float32]],
        NDArray[np.uint64],
        NDArray[np.float64],
        int,
    ]: ...
    def push(self, socket: int, host: str, port: int, datagram: bytes) -> None: ...
    def accept(self) -> None: ...
    def flush(self) -> None: ...
    def stats(self) -> dict[str, int]: ...
    def stop(self) -> None: ...

def livox_parse_header(datagram: bytes) -> dict[str, int]: ...
def livox_encode_command(
    cmd_id: int, seq_num: int, data: bytes = ..., *, cmd_type: int = 0, sender_type: int = 0
) -> bytes: ...
def livox_decode_command(frame: bytes) -> tuple[int, int, int, int, bytes]: ...
def livox_discovery_request(seq_num: int) -> bytes: ...
def livox_work_mode_request(seq_num: int, sampling: bool) -> bytes: ...
def livox_host_config_request(seq_num: int, host_ip: str, point_port: int, imu_port: int) -> bytes: ...
def livox_parse_discovery_ack(frame: bytes) -> dict[str, Any]: ...
def livox_parse_config_ack(frame: bytes) -> tuple[int, int]: ...
