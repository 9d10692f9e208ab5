"""How often does the photo check (:mod:`~insulator_rs.perception.photo_check`) call a good photo
unfit, and a bad one fit? Judged against the scene's ground truth, on a flight's own photos and on
bad photos made from them (issue 45, item 3).

For each photo a flight recorded (``summary.json``: the image file, its ``T_w_c`` and intrinsics):

* **the check**, as the flight runs it: the network (``insulator-sim`` at
  ``photo_check.PHOTO_DETECT_CONF``) on the image, the view projected from the *recorded* pose and
  intrinsics and the *localized* string (its centre from the flight's ``insulators.csv``, the
  mission's ``insulator_length``; the axis the true string's, as the flight's registry measures
  it to a degree);
* **the ground truth** (:func:`inspection_grade`): the true string through the photo's *true* pose
  and intrinsics qualifies by :mod:`~insulator_rs.evaluation.photo_coverage` (span >= 60 % of the
  long side, <= 2 mm/px), lies whole in the frame (``photo_quality.whole_in_frame``) and is smeared
  by at most ``photo_quality.MAX_BLUR_PX``.

The bad photos, each checked against the *recorded* pose and intrinsics (what the flight believes):

* **gimbal**: the true pose rotated by a few degrees about the camera's x (pitch) or y (yaw) axis;
* **zoom**: the true focal length a factor off the recorded;
* **blur**: a linear motion blur of several pixels (``cv2.filter2D``) across the string.

A gimbal offset and a wrong zoom are a rotation about the camera centre and a change of focal
length: for a distortion-free pinhole both are a homography of the recorded photo
(:func:`gimbal_offset`, :func:`wrong_zoom`), exact wherever the new ray saw the recorded frame; the
rest (the band the recorded frame did not see) is filled with the photo's median colour. The
string, whole in the recorded photo, is whole in what the warp carries. The warp resamples (a zoom
in magnifies): a "blurred" verdict on a warped photo is not counted. ``--render`` renders them
instead (the simulator's ray caster at the true pose and intrinsics: tens of seconds per 12 MP
photo here).

A perturbed photo counts as *bad* only where the ground truth says it is not inspection-grade (a
yaw of a few degrees can leave the string whole and fine: that one is counted apart, as
"still inspection-grade").

``insulator-rs eval photo-check --flight DIR --scene tower_b`` writes ``photo_check_study.csv``
(one row a photo) and ``photo_check_study.txt`` (the rates).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

import insulator_rs as ir
from insulator_rs.evaluation.localization_study import write_study
from insulator_rs.evaluation.photo_coverage import MAX_GSD_MM, MIN_SPAN_SHARE, photo_pose, string_in_photo
from insulator_rs.perception.photo_check import PHOTO_DETECT_CONF, check_photo, expected_view
from insulator_rs.perception.photo_verdict import Reason
from insulator_rs.perception.photo_quality import MAX_BLUR_PX, photo_quality
from insulator_rs.planning.framing import MIN_FILL

#: degrees: the gimbal offsets (about the camera's x axis: pitch, y: yaw). A string that fills
#: ~90 % of the frame's height leaves it at a pitch of ~0.3 degree per per cent of the height.
GIMBAL_OFFSETS_DEG: tuple[tuple[str, float], ...] = (("pitch", 2.0), ("pitch", -2.0), ("pitch", 4.0),
                                                     ("pitch", -4.0), ("yaw", 3.0), ("yaw", -5.0))
#: true focal length over the recorded: zoomed in (the string overflows), zoomed out (too small).
ZOOM_FACTORS: tuple[float, ...] = (1.25, 1.6, 0.8, 0.6)
#: px: linear motion blur lengths (the flight's own smear is 0.01 px).
BLUR_PX: tuple[float, ...] = (4.0, 8.0)
#: the rates the issue asks for
MAX_GOOD_UNFIT = 0.05
MIN_BAD_UNFIT = 0.95
MAX_RETAKES = 0.10

Detector = Callable[[np.ndarray], np.ndarray]
Renderer = Callable[[ir.CameraModel, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class StringTruth:
    """A true string (W): centre, unit axis, length (m)."""

    center: np.ndarray
    axis: np.ndarray
    length: float


@dataclass(frozen=True)
class StudyRow:
    """One checked photo: ``kind`` flight (as recorded), gimbal, zoom or blur; ``perturbation``
    its size; ``grade`` the ground truth's verdict; ``fit`` the check's (on a warped photo
    "blurred" is not counted: the warp's resampling softens it); ``reasons``, ``coverage`` and
    ``blur_extent`` the check's figures; ``true_span``/``true_gsd_mm`` the true string's."""

    tower: str
    file: str
    kind: str
    perturbation: str
    grade: bool
    fit: bool
    reasons: str
    coverage: float
    blur_extent: float
    true_span: float
    true_gsd_mm: float


def camera_from_record(rec: Mapping[str, Any]) -> ir.CameraModel:
    """The intrinsics of a photo record's ``camera``."""
    return ir.CameraModel(rec["fx"], rec["fy"], rec["cx"], rec["cy"], rec["width"], rec["height"],
                          dist=list(rec.get("dist", [0.0] * 5)))


def _K(camera: ir.CameraModel) -> np.ndarray:
    return np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])


def _rotation(axis: str, deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    if axis == "pitch":  # about the camera's x (right): the view tilts up/down
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    if axis == "yaw":  # about the camera's y (down): the view pans left/right
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    raise ValueError(f"axis: 'pitch' or 'yaw', got {axis!r}")


def _require_pinhole(camera: ir.CameraModel) -> None:
    if any(abs(d) > 0 for d in camera.dist):
        raise ValueError("camera: the homography warp needs a distortion-free camera; render instead (--render)")


def _warp(image: np.ndarray, H_dst_to_src: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    fill = tuple(float(v) for v in np.median(image.reshape(-1, image.shape[2] if image.ndim == 3 else 1), axis=0))
    return cv2.warpPerspective(image, H_dst_to_src, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=fill)


def gimbal_offset(image: np.ndarray, camera: ir.CameraModel, T_w_c: np.ndarray, axis: str,
                  deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The photo ``image`` (taken by ``camera`` at ``T_w_c``) as the camera rotated by ``deg``
    about its ``axis`` would have taken it, and that true pose: the homography K R K^-1."""
    _require_pinhole(camera)
    R = _rotation(axis, deg)
    T_true = np.asarray(T_w_c, dtype=np.float64).copy()
    T_true[:3, :3] = T_true[:3, :3] @ R
    K = _K(camera)
    return _warp(image, K @ R @ np.linalg.inv(K)), T_true


def zoomed(camera: ir.CameraModel, factor: float) -> ir.CameraModel:
    """``camera`` with its focal length times ``factor`` (the principal point kept)."""
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"factor: must be finite and > 0, got {factor}")
    return ir.CameraModel(camera.fx * factor, camera.fy * factor, camera.cx, camera.cy, camera.width,
                          camera.height, dist=list(camera.dist))


def wrong_zoom(image: np.ndarray, camera: ir.CameraModel, factor: float) -> tuple[np.ndarray, ir.CameraModel]:
    """The photo as the same pose at ``factor`` times the focal length would have taken it, and
    that true camera: the homography K K'^-1."""
    _require_pinhole(camera)
    true_cam = zoomed(camera, factor)
    return _warp(image, _K(camera) @ np.linalg.inv(_K(true_cam))), true_cam


def motion_blur(image: np.ndarray, px: float, angle_deg: float) -> np.ndarray:
    """``image`` smeared along ``angle_deg`` (0: along the rows) over ``px`` pixels (a line kernel)."""
    if not (math.isfinite(px) and px >= 1):
        raise ValueError(f"px: must be finite and >= 1, got {px}")
    n = int(math.ceil(px)) | 1
    kernel = np.zeros((n, n), np.float32)
    c = n // 2
    a = math.radians(angle_deg)
    for t in np.linspace(-0.5 * px, 0.5 * px, 4 * n):
        kernel[int(round(c + t * math.sin(a))), int(round(c + t * math.cos(a)))] = 1.0
    return cv2.filter2D(image, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REPLICATE)


def true_string_in(camera: ir.CameraModel, T_w_c: np.ndarray, truths: Sequence[StringTruth]) -> StringTruth:
    """The true string the photo is of: the one spanning most of the frame."""
    return max(truths, key=lambda t: string_in_photo(camera, T_w_c, t.center, t.axis, t.length)["span_share"])


def inspection_grade(camera: ir.CameraModel, T_w_c: np.ndarray, truth: StringTruth,
                     blur_px: float = 0.0) -> tuple[bool, float, float]:
    """The ground truth's verdict on a photo by ``camera`` at its true ``T_w_c`` (W from camera)
    of the true string: (inspection-grade, span share, GSD mm/px) (module docstring)."""
    fig = string_in_photo(camera, T_w_c, truth.center, truth.axis, truth.length)
    q = photo_quality(camera, np.linalg.inv(T_w_c), truth.center, truth.axis, length=truth.length)
    gsd = math.inf if fig["gsd_mm"] is None else float(fig["gsd_mm"])
    good = fig["span_share"] >= MIN_SPAN_SHARE and gsd <= MAX_GSD_MM and q.whole_in_frame and blur_px <= MAX_BLUR_PX
    return bool(good), float(fig["span_share"]), gsd


def judge(detector: Detector, image: np.ndarray, camera: ir.CameraModel, T_w_c: np.ndarray,
          localized_center: np.ndarray, axis: np.ndarray, length: float) -> Any:
    """The check as the flight runs it on a single shot aimed at the localized centre."""
    view = expected_view(camera, np.linalg.inv(T_w_c), localized_center, localized_center, axis, length,
                         required_span=MIN_FILL)
    return check_photo(detector, image, view)


def study_photo(detector: Detector, tower: str, name: str, image: np.ndarray, camera: ir.CameraModel,
                T_w_c: np.ndarray, localized_center: np.ndarray, length: float, truths: Sequence[StringTruth],
                *, render: Renderer | None = None) -> list[StudyRow]:
    """The rows of one recorded photo: itself and its gimbal, zoom and blur variants (module docstring).
    ``render(camera, T_w_c)``: render a variant instead of warping the photo."""
    truth = true_string_in(camera, T_w_c, truths)
    rows: list[StudyRow] = []

    def row(kind: str, what: str, img: np.ndarray, true_cam: ir.CameraModel, true_T: np.ndarray,
            blur: float = 0.0, warped: bool = False) -> None:
        grade, span, gsd = inspection_grade(true_cam, true_T, truth, blur)
        check = judge(detector, img, camera, T_w_c, localized_center, truth.axis, length)
        # a warp resamples the photo (a zoom in magnifies it): softer than a render at that pose
        # would be, so "blurred" on a warped photo is the warp's, and not counted
        reasons = [r for r in check.reasons if not (warped and r == Reason.NOT_SHARP.value)]
        rows.append(StudyRow(tower, name, kind, what, grade, not reasons, "; ".join(check.reasons),
                             float(check.coverage or 0.0), float(check.blur_extent or 1.0), span, gsd))

    row("flight", "", image, camera, T_w_c)
    for axis, deg in GIMBAL_OFFSETS_DEG:
        warped, T_true = gimbal_offset(image, camera, T_w_c, axis, deg)
        row("gimbal", f"{axis} {deg:+g} deg", warped if render is None else render(camera, T_true), camera, T_true,
            warped=render is None)
    for factor in ZOOM_FACTORS:
        warped, true_cam = wrong_zoom(image, camera, factor)
        row("zoom", f"focal x{factor:g}", warped if render is None else render(true_cam, T_w_c), true_cam, T_w_c,
            warped=render is None)
    # the smear across the string's axis (the worst direction for its sheds' edges)
    uv_axis = np.linalg.inv(T_w_c)[:3, :3] @ truth.axis
    across = math.degrees(math.atan2(uv_axis[1], uv_axis[0])) + 90.0
    for px in BLUR_PX:
        row("blur", f"{px:g} px", motion_blur(image, px, across), camera, T_w_c, blur=px)
    return rows


def localized_centers(folder: Path) -> dict[int, np.ndarray]:
    """Insulator id -> localized centre (W, m) from a flight's ``insulators.csv``."""
    with (folder / "insulators.csv").open() as f:
        return {int(r["id"]): np.array([float(r["x_m"]), float(r["y_m"]), float(r["z_m"])]) for r in csv.DictReader(f)}


def scaled_to_width(camera: ir.CameraModel, width: int) -> ir.CameraModel:
    """``camera`` resampled to ``width`` px wide (focal lengths, principal point and height scaled)."""
    if width < 1:
        raise ValueError(f"width: must be >= 1, got {width}")
    k = width / camera.width
    return ir.CameraModel(camera.fx * k, camera.fy * k, (camera.cx + 0.5) * k - 0.5, (camera.cy + 0.5) * k - 0.5,
                          width, round(camera.height * k), dist=list(camera.dist))


def study_flight(folder: Path, tower: str, truths: Sequence[StringTruth], length: float, detector: Detector,
                 *, render: Renderer | None = None, limit: int | None = None, stride: int = 1,
                 photo_width: int | None = None, progress: Callable[[str], None] | None = None) -> list[StudyRow]:
    """The rows of every ``stride``-th single-shot photo of the flight in ``folder`` (at most
    ``limit``). ``photo_width``: render each photo again at its recorded pose at this width
    (``render`` or the caller's renderer must be given) instead of reading the flight's file (a
    flight flown at a reduced --photo-scale gives the poses of the full-size photos)."""
    if stride < 1:
        raise ValueError(f"stride: must be >= 1, got {stride}")
    summary = json.loads((folder / "summary.json").read_text())
    centers = localized_centers(folder)
    photos = [p for p in summary.get("photos", []) if p.get("tiles", 1) == 1 and p.get("T_w_c") is not None
              and p.get("insulator_id") in centers]
    rows: list[StudyRow] = []
    for p in photos[::stride][:limit]:
        camera = camera_from_record(p["camera"])
        if photo_width is not None:
            if render is None:
                raise ValueError("photo_width: needs a renderer")
            camera = scaled_to_width(camera, photo_width)
            image = render(camera, photo_pose(p))
        else:
            read = cv2.imread(str(folder / p["file"]), cv2.IMREAD_COLOR)
            if read is None:
                raise ValueError(f"flight: cannot read {folder / p['file']}")
            image = read
        rows += study_photo(detector, tower, p["file"], image, camera, photo_pose(p),
                            centers[p["insulator_id"]], length, truths, render=render if photo_width is None else None)
        if progress is not None:
            progress(f"{tower} {p['file']}: checked with its variants")
    return rows


def rates(rows: Iterable[StudyRow]) -> dict[str, Any]:
    """The issue's rates: good photos (the flight's, inspection-grade) called unfit; bad photos
    (not inspection-grade, any kind) called unfit; the retakes the check orders on the flight's
    photos (one per unfit photo) over the flight's photos; perturbed photos still inspection-grade."""
    rows = list(rows)
    flight = [r for r in rows if r.kind == "flight"]
    good = [r for r in flight if r.grade]
    bad = [r for r in rows if not r.grade]
    still = [r for r in rows if r.kind != "flight" and r.grade]
    per_kind = {k: [r for r in bad if r.kind == k] for k in ("flight", "gimbal", "zoom", "blur")}

    def share(rs: Sequence[StudyRow], unfit: bool = True) -> float | None:
        return None if not rs else sum((not r.fit) == unfit for r in rs) / len(rs)

    return {"good": len(good), "good_unfit": share(good), "bad": len(bad), "bad_unfit": share(bad),
            "bad_unfit_by_kind": {k: (len(v), share(v)) for k, v in per_kind.items()},
            "flight_photos": len(flight), "retakes": share(flight),
            "still_grade": len(still), "still_grade_unfit": share(still)}


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def format_table(rows: Sequence[StudyRow]) -> str:
    """The rates per tower and in all, against the issue's limits."""
    lines = [f"{'tower':6} {'good':>5} {'good unfit':>11} {'bad':>5} {'bad unfit':>10} {'gimbal':>14} "
             f"{'zoom':>14} {'blur':>14} {'retakes':>8} {'still-grade unfit':>18}"]
    towers = list(dict.fromkeys(r.tower for r in rows))
    for t in [*towers, "all"]:
        rs = [r for r in rows if t == "all" or r.tower == t]
        k = rates(rs)
        by = k["bad_unfit_by_kind"]
        cells = [f"{_pct(by[x][1])} of {by[x][0]}" for x in ("gimbal", "zoom", "blur")]
        lines.append(f"{t:6} {k['good']:>5} {_pct(k['good_unfit']):>11} {k['bad']:>5} {_pct(k['bad_unfit']):>10} "
                     f"{cells[0]:>14} {cells[1]:>14} {cells[2]:>14} {_pct(k['retakes']):>8} "
                     f"{_pct(k['still_grade_unfit']) + ' of ' + str(k['still_grade']):>18}")
    k = rates(rows)
    ok = (k["good_unfit"] is not None and k["good_unfit"] <= MAX_GOOD_UNFIT and k["bad_unfit"] is not None
          and k["bad_unfit"] >= MIN_BAD_UNFIT and k["retakes"] is not None and k["retakes"] <= MAX_RETAKES)
    lines.append(f"limits: good unfit <= {_pct(MAX_GOOD_UNFIT)}, bad unfit >= {_pct(MIN_BAD_UNFIT)}, "
                 f"retakes <= {_pct(MAX_RETAKES)}: {'met' if ok else 'NOT met'}")
    return "\n".join(lines)


def tower_truths(scene: str) -> tuple[list[StringTruth], Any]:
    """The true strings of a scene (name or file) and its mesh."""
    from insulator_rs.sim.towers import load_tower

    tower = load_tower(scene)
    return [StringTruth(np.asarray(i.center, float), np.asarray(i.axis, float), float(i.length))
            for i in tower.insulators], tower.mesh


def ray_cast_renderer(mesh: Any) -> Renderer:
    """Render a photo with the simulator's ray caster at (camera, T_w_c)."""
    from insulator_rs.sim.camera_render import Camera

    def render(camera: ir.CameraModel, T_w_c: np.ndarray) -> np.ndarray:
        frame = Camera(camera, np.eye(4)).render(mesh, T_w_c, seed=1)
        return np.ascontiguousarray(frame.rgb[:, :, ::-1])

    return render


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--flight", type=Path, nargs="+", required=True,
                        help="flight report folders (summary.json with T_w_c, images/, insulators.csv)")
    parser.add_argument("--scene", nargs="+", required=True, help="the scene of each flight (tower_a, tower_b, a TOML)")
    parser.add_argument("--mission", nargs="+", default=None,
                        help="the mission of each flight (its insulator_length; default: the scene's example)")
    parser.add_argument("--render", action="store_true",
                        help="render the gimbal and zoom variants with the ray caster instead of warping the photo")
    parser.add_argument("--limit", type=int, default=None, help="at most this many photos per flight (default: every photo)")
    parser.add_argument("--stride", type=int, default=1, help="every this many-th photo of a flight")
    parser.add_argument("--photo-width", type=int, default=None,
                        help="render each photo again at its recorded pose, this many px wide (a flight flown at "
                             "--photo-scale 0.2 gives the full-size photos' poses: 4000); the variants are warped (default: "
                             "the photos as the flight wrote them)")
    parser.add_argument("--out", type=Path, default=Path("results/photo_check"), help="folder for the table")


def run(args: argparse.Namespace) -> int:
    from insulator_rs.mission.config import load_mission
    from insulator_rs.ports.detector import open_network_detector

    if len(args.scene) != len(args.flight) or (args.mission is not None and len(args.mission) != len(args.flight)):
        print("insulator-rs eval photo-check: error: give one --scene (and --mission) per --flight")
        return 2
    missions_dir = Path(ir.__file__).resolve().parent / "missions"
    detector = open_network_detector("insulator-sim", conf=PHOTO_DETECT_CONF)
    rows: list[StudyRow] = []
    for i, (folder, scene) in enumerate(zip(args.flight, args.scene)):
        mission = Path(args.mission[i]) if args.mission else missions_dir / f"{Path(scene).stem}.toml"
        truths, mesh = tower_truths(scene)
        rows += study_flight(folder, Path(scene).stem, truths, load_mission(mission).inspection.insulator_length,
                             detector, render=ray_cast_renderer(mesh) if args.render or args.photo_width else None,
                             limit=args.limit, stride=args.stride, photo_width=args.photo_width, progress=print)
    return write_study(args.out, "photo_check_study", rows, format_table(rows))
