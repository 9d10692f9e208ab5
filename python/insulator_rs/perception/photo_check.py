"""Is the photo just taken usable, judged on the photo itself? The check after every shot.

:mod:`~insulator_rs.perception.photo_quality` gives a photo's figures from the pose and the
localized string (what the photo should hold); this module looks at what it does hold: the
detector is run on the photo once and, from its boxes, the insulator's box is measured:

* **which box**: the one nearest the planned target's projection through the photo's own pose
  and intrinsics (distance from the point to the box, 0 inside; ties by centre distance);
* **cut**: the box reaches the image border (within :data:`BORDER_MARGIN` of the dimension, at
  least :data:`BORDER_MARGIN_PX`). A tile of a long string is planned to leave the frame: there a
  side where the localized string, projected through the photo's pose, runs out of the frame is
  open, not cut (a single shot has no open side: the whole string belongs inside);
* **too small**: the box's longer side spans less than ``min_span`` of the frame's long side:
  the required fill (the loop gives the planned framing's ``MIN_FILL``), or :data:`PLANNED_SHARE`
  of what the projected string spans where the shot cannot give that much (a fixed lens, a
  viewpoint pushed out by a safety volume: a retake would not make it bigger);
* **off centre**: the box's centre is more than :data:`MAX_OFFSET` of the frame's width (height)
  from the image centre, judged on an axis whose both sides are closed (on an open axis the box
  ends at the border by design);
* **not sharp**: the variance of the Laplacian (``cv2.Laplacian``, 3x3, on the grey image inside
  the box, shrunk to at most :data:`ANALYSIS_PX`) is below :data:`MIN_SHARPNESS` (see there for
  the figures it was set on).

A string the detector sees in pieces (the shipped ``insulator-sim`` network, trained on the
detection camera's far views, boxes the sheds of a close-up one by one) is one insulator: the
box nearest the target is merged with every box that meets the projected string's box widened
by :data:`MAX_OFFSET` of the frame (the corridor where the plan puts it).

The verdict is a :class:`~insulator_rs.perception.photo_verdict.PhotoVerdict` (each reason
above a :class:`~insulator_rs.perception.photo_verdict.Reason`): the one the flight writes into
``summary.json`` and every reader takes from there.

A detector that raises is recorded as the check's ``error`` and the photo is unfit (retaken);
it never ends the flight. The detector runs once per call (``detect_s`` says what it cost).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import cv2
import numpy as np

import insulator_rs as ir
from insulator_rs.perception.photo_verdict import PhotoVerdict, Reason

#: Share of the frame's width (height) the box centre may stray from the image centre. The
#: shot aims at the localized centre: a 5 cm error of the centre moves the string ~90 px of
#: 4000 (2 %) at 0.56 mm/px; 10 % (400 px) is an aim gone wrong (a settle cut short, a gust).
MAX_OFFSET = 0.10
#: A box edge this close to the border (share of the dimension, and at least
#: :data:`BORDER_MARGIN_PX`) touches it: the detectors clip their boxes to the image.
BORDER_MARGIN = 0.005
BORDER_MARGIN_PX = 2.0
#: The projected string must end this far inside the frame (share of the dimension) for a side to
#: be closed: a string planned to reach the border (a tile) leaves that side open.
OPEN_MARGIN = 0.01
#: A box this share of the projected string's span is as big as the shot was planned (the
#: detector's box and the localized length err by a few per cent).
PLANNED_SHARE = 0.90
#: Variance of the 3x3 Laplacian (8-bit counts^2) of the box's crop (at ANALYSIS_PX) below which
#: a photo is not sharp. Measured on the simulator's renders of the zoomed string: sharp, 1250-2200
#: at the tests' 0.2 photo scale (the string ~550 px long; small scene) and 416 at the full 12 MP
#: (tower B, the crop shrunk to 1000 px); the full-resolution photo after cv2.GaussianBlur sigma
#: 2.5 px (1.4 mm on the string) 47, sigma 5 px 8; the 0.2-scale ones after sigma 1.5-3 px stay
#: under it (tests/test_photo_check.py). The image noise alone (2 counts, white) gives
#: 20 sigma^2 = 80. 150 sits above the noise floor, a factor ~3 over the blurred 12 MP figure and
#: under the sharp one. Camera-dependent (contrast, noise, optics): set it on the camera's photos.
MIN_SHARPNESS = 150.0
#: px: the box's crop is judged at most this long (area-averaged down to it): the figure then
#: depends little on the photo's resolution (a 12 MP photo's string spans ~2700 px, the 0.2
#: scale render's ~550 px), and 1000 px along a 2 m string is the 2 mm/px an inspection needs,
#: so a blur that spoils that detail still shows. Also bounds the cost on a 12 MP photo.
ANALYSIS_PX = 1000


@dataclass(frozen=True)
class ExpectedView:
    """Where the plan puts the string in the photo: ``target_px`` (u, v) the planned target's
    projection (None: behind the camera); ``string_box`` (x1, y1, x2, y2) of the localized string
    projected, unclipped (None: not wholly in front of the camera); ``width``/``height`` of the
    image; ``min_span`` the share of the long side the box must span; ``tiled``: the shot is one
    of a long string's tiles (the string is planned to run out of the frame)."""

    target_px: tuple[float, float] | None
    string_box: tuple[float, float, float, float] | None
    width: int
    height: int
    min_span: float
    tiled: bool = False

    def open_sides(self) -> tuple[bool, bool, bool, bool]:
        """(left, top, right, bottom): the string is planned to leave the frame there (a tile only)."""
        if self.string_box is None or not self.tiled:
            return (False, False, False, False)
        x1, y1, x2, y2 = self.string_box
        mx, my = OPEN_MARGIN * self.width, OPEN_MARGIN * self.height
        return (x1 < mx, y1 < my, x2 > self.width - mx, y2 > self.height - my)


def expected_view(camera: ir.CameraModel, T_c_w: np.ndarray, target: np.ndarray, center: np.ndarray,
                  axis: np.ndarray, length: float, *, required_span: float, tiled: bool = False) -> ExpectedView:
    """The :class:`ExpectedView` of a photo by ``camera`` (as rendered) at ``T_c_w`` (W -> camera)
    aimed at ``target`` (W) of the string ``length`` m at ``center`` along ``axis`` (W);
    ``required_span``: the share of the long side the insulator must span, lowered to
    PLANNED_SHARE of the projected string's where that is less (the module docstring);
    ``tiled``: the shot frames one tile of the string."""
    if not (math.isfinite(required_span) and 0 < required_span <= 1):
        raise ValueError(f"required_span: must be in (0, 1], got {required_span}")
    if not (math.isfinite(length) and length > 0):
        raise ValueError(f"length: must be finite and > 0, got {length}")
    u = np.asarray(axis, dtype=np.float64).reshape(3)
    u = u / np.linalg.norm(u)
    c = np.asarray(center, dtype=np.float64).reshape(3)
    ends = np.linspace(-0.5, 0.5, 9)[:, None] * length * u + c  # along the string: distortion bends it
    pts = np.vstack([np.asarray(target, dtype=np.float64).reshape(1, 3), ends])
    uv, valid = ir.project_points(pts, np.asarray(T_c_w, dtype=np.float64), camera)
    target_px = (float(uv[0, 0]), float(uv[0, 1])) if valid[0] else None
    box = None
    w, h = int(camera.width), int(camera.height)
    min_span = float(required_span)
    if np.all(valid[1:]):
        lo, hi = uv[1:].min(axis=0), uv[1:].max(axis=0)
        box = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
        clo, chi = np.clip(lo, 0, [w, h]), np.clip(hi, 0, [w, h])
        min_span = min(min_span, PLANNED_SHARE * float(np.max(chi - clo)) / max(w, h))
    return ExpectedView(target_px, box, w, h, min_span, bool(tiled))


@dataclass(frozen=True)
class PhotoCheck:
    """The verdict on one photo and the figures it was decided on (module docstring). ``box``: the
    insulator's (x1, y1, x2, y2, score) in the photo's pixels, None when none was detected;
    ``detections``: boxes the detector gave; ``span_share``: the box's longer side over the
    frame's long side; ``offset``: (dx, dy) of the box centre from the image centre over the
    width and height (None on an open axis); ``sharpness``: see :data:`MIN_SHARPNESS`;
    ``detect_s``/``check_s``: wall seconds of the detector and of the measurements."""

    verdict: PhotoVerdict
    box: list[float] | None = None
    detections: int = 0
    cut_sides: list[str] = field(default_factory=list)
    span_share: float = 0.0
    min_span: float = 0.0
    offset: list[float | None] = field(default_factory=lambda: [None, None])
    sharpness: float | None = None
    error: str | None = None
    detect_s: float = 0.0
    check_s: float = 0.0

    @property
    def fit(self) -> bool:
        return self.verdict.fit

    @property
    def reasons(self) -> list[str]:
        """Why unfit, in words ([] when fit)."""
        return self.verdict.unfit_reasons

    def as_dict(self) -> dict[str, Any]:
        """The record of ``summary.json``: the figures and ``verdict`` (its JSON), and ``fit``
        and ``reasons`` read off that verdict for the flight's own tally of the checks."""
        out = {k: v for k, v in asdict(self).items() if k != "verdict"}
        return {"verdict": self.verdict.to_json(), "fit": self.fit, "reasons": self.reasons, **out}


def _pick(boxes: np.ndarray, target: tuple[float, float] | None, width: int, height: int) -> int:
    """The index of the box nearest ``target`` (the image centre when None)."""
    tx, ty = target if target is not None else (0.5 * width, 0.5 * height)
    dx = np.maximum(np.maximum(boxes[:, 0] - tx, tx - boxes[:, 2]), 0.0)
    dy = np.maximum(np.maximum(boxes[:, 1] - ty, ty - boxes[:, 3]), 0.0)
    centre = np.hypot(0.5 * (boxes[:, 0] + boxes[:, 2]) - tx, 0.5 * (boxes[:, 1] + boxes[:, 3]) - ty)
    return int(np.lexsort((centre, np.hypot(dx, dy)))[0])


def sharpness(image: np.ndarray, box: tuple[float, float, float, float] | None = None) -> float:
    """The variance of the 3x3 Laplacian of ``image`` (BGR or grey uint8) inside ``box`` (pixels;
    None: the whole image), the crop first shrunk (area-averaged) to at most
    :data:`ANALYSIS_PX` along its longer side. 0 for a crop under 3x3 pixels."""
    h, w = image.shape[:2]
    if box is not None:
        x1, y1 = max(0, int(math.floor(box[0]))), max(0, int(math.floor(box[1])))
        x2, y2 = min(w, int(math.ceil(box[2]))), min(h, int(math.ceil(box[3])))
        image = image[y1:y2, x1:x2]
    if image.shape[0] < 3 or image.shape[1] < 3:
        return 0.0
    grey = image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY)
    k = ANALYSIS_PX / max(grey.shape[:2])
    if k < 1.0:
        grey = cv2.resize(grey, (max(3, round(grey.shape[1] * k)), max(3, round(grey.shape[0] * k))),
                          interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(grey, cv2.CV_64F, ksize=1).var())


def _merged(boxes: np.ndarray, k: int, view: ExpectedView) -> np.ndarray:
    """Box ``k`` united with the boxes that meet the projected string's box widened by
    MAX_OFFSET of the frame (a string boxed in pieces); box ``k`` alone without a projection."""
    box = boxes[k, :4].copy()
    if view.string_box is None:
        return box
    mx, my = MAX_OFFSET * view.width, MAX_OFFSET * view.height
    x1, y1, x2, y2 = view.string_box
    meets = (boxes[:, 0] <= x2 + mx) & (boxes[:, 2] >= x1 - mx) & (boxes[:, 1] <= y2 + my) & (boxes[:, 3] >= y1 - my)
    if not meets[k]:
        return box
    part = boxes[meets, :4]
    return np.array([part[:, 0].min(), part[:, 1].min(), part[:, 2].max(), part[:, 3].max()])


def check_boxes(image: np.ndarray, boxes: np.ndarray, view: ExpectedView) -> PhotoCheck:
    """Judge ``image`` from the detector's ``boxes`` on it ((M, 4|5) pixels) against ``view``."""
    t0 = time.perf_counter()
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, boxes.shape[1] if np.ndim(boxes) == 2 else 5)
    h, w = image.shape[:2]
    if len(b) == 0:
        return PhotoCheck(PhotoVerdict.unfit([Reason.NOT_DETECTED]), min_span=view.min_span,
                          check_s=time.perf_counter() - t0)
    k = _pick(b, view.target_px, w, h)
    x1, y1, x2, y2 = (float(v) for v in _merged(b, k, view))
    score = float(b[k, 4]) if b.shape[1] > 4 else 1.0
    reasons: list[Reason] = []
    mx, my = max(BORDER_MARGIN_PX, BORDER_MARGIN * w), max(BORDER_MARGIN_PX, BORDER_MARGIN * h)
    touches = (x1 <= mx, y1 <= my, x2 >= w - mx, y2 >= h - my)
    is_open = view.open_sides()
    names = ("left", "top", "right", "bottom")
    cut = [n for n, t, o in zip(names, touches, is_open) if t and not o]
    if cut:
        reasons.append(Reason.CUT)
    span = max(x2 - x1, y2 - y1) / max(w, h)
    if span < view.min_span:
        reasons.append(Reason.TOO_SMALL)
    off_x = None if (is_open[0] or is_open[2]) else (0.5 * (x1 + x2) - 0.5 * w) / w
    off_y = None if (is_open[1] or is_open[3]) else (0.5 * (y1 + y2) - 0.5 * h) / h
    if any(o is not None and abs(o) > MAX_OFFSET for o in (off_x, off_y)):
        reasons.append(Reason.OFF_CENTRE)
    sharp = sharpness(image, (x1, y1, x2, y2))
    if sharp < MIN_SHARPNESS:
        reasons.append(Reason.NOT_SHARP)
    verdict = PhotoVerdict.unfit(reasons) if reasons else PhotoVerdict.passed()
    return PhotoCheck(verdict, box=[x1, y1, x2, y2, score], detections=len(b),
                      cut_sides=cut, span_share=float(span), min_span=view.min_span, offset=[off_x, off_y],
                      sharpness=sharp, check_s=time.perf_counter() - t0)


def check_photo(detector: Callable[[np.ndarray], np.ndarray], image: np.ndarray, view: ExpectedView) -> PhotoCheck:
    """Run ``detector`` on ``image`` once and judge it (:func:`check_boxes`). A detector that
    raises gives an unfit check carrying the error (the flight goes on)."""
    t0 = time.perf_counter()
    try:
        boxes = np.asarray(detector(image), dtype=np.float64)
    except Exception as exc:  # noqa: BLE001 - any adapter's failure costs this check, never the flight
        error = f"{type(exc).__name__}: {exc}"
        return PhotoCheck(PhotoVerdict.unfit([Reason.DETECTOR_ERROR], error), min_span=view.min_span,
                          error=error, detect_s=time.perf_counter() - t0)
    detect_s = time.perf_counter() - t0
    if boxes.ndim != 2 or boxes.shape[1] not in (4, 5):
        error = f"boxes: expected (M, 4|5), got shape {boxes.shape}"
        return PhotoCheck(PhotoVerdict.unfit([Reason.DETECTOR_ERROR], error), min_span=view.min_span,
                          error=error, detect_s=detect_s)
    check = check_boxes(image, boxes, view)
    return replace(check, detect_s=detect_s)
