"""Is the photo just taken usable? The check after every shot: its framing from the geometry,
its image from the photo.

**Framing** (where the string lies in the photo, how big, how fine) is judged from the localized
string projected through the photo's own pose and intrinsics (:func:`expected_view`; the GSD and
"whole in frame" are :func:`~insulator_rs.perception.photo_quality.photo_quality`'s figures): a
close-up is the detector's weak spot (the shipped ``insulator-sim`` network, trained on the
detection camera's far views, boxes single sheds of a close-up at low scores), so its box no
longer measures the string:

* **cut**: the string's axis reaches the border (:data:`BORDER_MARGIN` of the dimension, at least
  :data:`BORDER_MARGIN_PX`), or, on a single shot, its rims leave the frame (``whole_in_frame``). A tile of a long string is planned to leave the frame: there a
  side where the projected string runs out of the frame is open, not cut (a single shot has no
  open side: the whole string belongs inside);
* **too small**: the part in the frame spans less than ``min_span`` of the long side: the
  required fill (the loop gives the planned framing's ``MIN_FILL``), or :data:`PLANNED_SHARE` of
  what the whole projected string spans where the shot cannot give that much (a fixed lens, a
  viewpoint pushed out by a safety volume: a retake would not make it bigger);
* **off centre**: the part in the frame has its centre more than :data:`MAX_OFFSET` of the
  width (height) from the image centre, on an axis whose both sides are closed.
* **not sharp**: the blur extent of the string's region (:func:`blur_extent`) is above
  :data:`MAX_BLUR_EXTENT` (see there for the figures it was set on).

The GSD (mm/px at the string's far end) is recorded (``gsd_mm``), not judged: the framing chose
it, and a retake at the same framing would not make it finer.

**Image** (does the photo hold what the geometry says, and is it sharp there), from the evidence
the network gives reliably on a close-up, its boxes in pieces:

* **not where planned**: the detector's boxes (any score it returns; the flight's photo detector
  runs at :data:`PHOTO_DETECT_CONF`), each widened by :data:`COVER_TOLERANCE` of the long side,
  cover less than :data:`MIN_COVERAGE` of the projected string's samples inside the frame, from
  the first covered to the last (:func:`coverage`). A gimbal that is off, a zoom wider than
  recorded, a string elsewhere or shorter than localized: the pieces lie elsewhere than the
  projection, or end short of it. No box at all is **no insulator detected**. A zoom *narrower*
  than recorded is not caught: the string, planned to fill ~90 % of the frame, then runs past the
  border, and the pieces can reach no farther than the border (the study's known gap);
* **blurred**: the blur extent (:func:`blur_extent`, a no-reference measure after Crete-Roffet et
  al.) of the projected string's region, at the photo's own pixels, is over
  :data:`MAX_BLUR_EXTENT` (see there for the figures it was set on, and why not the Laplacian
  variance, which the check still records as ``sharpness``).

The check's ``box`` is the union of the boxes that meet the projected string's corridor (its box
widened by :data:`MAX_OFFSET` of the frame): the string as the detector saw it, for the record.

The verdict is a :class:`~insulator_rs.perception.photo_verdict.PhotoVerdict` (each reason
above a :class:`~insulator_rs.perception.photo_verdict.Reason`): the one the flight writes into
``summary.json`` and every reader takes from there.

A detector that raises is recorded as the check's ``error`` and the photo is unfit (retaken);
it never ends the flight. The detector runs once per call (``detect_s`` says what it cost).
The rates this rule gives against the ground truth: ``insulator-rs eval photo-check``
(:mod:`~insulator_rs.evaluation.photo_check_study`).
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
from insulator_rs.perception.photo_quality import STRING_DIAMETER, photo_quality
from insulator_rs.perception.photo_verdict import PhotoVerdict, Reason
from insulator_rs.perception.shed_pattern import PERIOD_RANGE, WINDOW_PERIODS, shed_evidence

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
#: A string in the frame this share of its whole projection is as big as the shot can give (the
#: localized length errs by a few per cent).
PLANNED_SHARE = 0.90
#: The blur extent (:func:`blur_extent`, Crete-Roffet et al. 2007: how little a further 9-px box
#: blur changes the image's neighbour differences, 0 sharp .. 1 flat) above which the photo is
#: blurred. Measured on tower B's 12 MP photos (the string's region at full resolution): sharp
#: 0.163-0.176; a linear motion blur of 2 px across the string 0.25, 4 px 0.40, 8 px 0.58. The
#: figure is a ratio, so it depends little on the string's contrast and the photo's scale (the
#: Laplacian variance of the same photos: sharp 200-320 at 12 MP, 800-1000 at 0.3 scale, a 4 px
#: blur 220-390 at 0.3 scale: no one threshold serves both). Set on the simulator's pixel-sharp
#: renders: a real lens's softness raises the sharp figure; set it on the camera's photos.
MAX_BLUR_EXTENT = 0.21
#: px: the Crete-Roffet re-blur length (the paper's 9).
REBLUR_PX = 9
#: px: the Laplacian variance (the record's ``sharpness``) is taken on the crop shrunk to at most
#: this long (area-averaged): comparable across photo sizes, and a bounded cost on 12 MP.
ANALYSIS_PX = 1000


#: Confidence threshold of the network run on a photo. The shipped ``insulator-sim`` boxes a
#: 12 MP close-up's sheds at 0.05-0.5: at the detection threshold (0.25) 5 of tower B's 23 good
#: photos held no box and the rest covered 0-95 % of the string; at 0.05 every one covered
#: 95-100 % (``insulator-rs eval photo-check``). A low-score box only counts where the geometry
#: puts the string (:data:`MIN_COVERAGE`), so the low threshold admits no far false box.
PHOTO_DETECT_CONF = 0.05
#: Share of the projected string (its samples in the frame, first to last covered, :func:`coverage`)
#: the detector's boxes must cover. Tower B's 12 MP photos: good 0.93-1.0; the gimbal 2 degrees
#: off in pitch (the string ~380 px along itself) 0.85-0.88; the focal 0.8x the recorded (the string
#: shorter than planned) 0.66-0.90; a yaw of 3 degrees 0-0.07 (``insulator-rs eval photo-check``).
MIN_COVERAGE = 0.92
#: Share of the long side a box is widened by before it covers a sample: the projection of the
#: axis runs down the string's middle, a shed's box may end a little short of it (the
#: localization error: 5 cm ~ 90 px of 4000 at 0.56 mm/px, mostly along the line of sight).
COVER_TOLERANCE = 0.01
#: Samples along the projected string (end to end) for the coverage.
STRING_SAMPLES = 41


@dataclass(frozen=True)
class ExpectedView:
    """Where the plan puts the string in the photo: ``target_px`` (u, v) the planned target's
    projection (None: behind the camera); ``string_box`` (x1, y1, x2, y2) of the localized string
    projected, unclipped (its axis; None: not wholly in front of the camera);
    ``width``/``height`` of the image; ``min_span`` the share of the long side the string must
    span; ``tiled``: the shot is one of a long string's tiles (the string is planned to run out of
    the frame); ``string_px``: the axis's :data:`STRING_SAMPLES` projected points ((u, v), end to
    end; empty when not all in front of the camera); ``gsd_mm``: mm/px at the string's far end
    (inf behind the camera); ``whole``: the string with its rims inside the frame."""

    target_px: tuple[float, float] | None
    string_box: tuple[float, float, float, float] | None
    width: int
    height: int
    min_span: float
    tiled: bool = False
    string_px: tuple[tuple[float, float], ...] = ()
    gsd_mm: float = 0.0
    whole: bool = True

    def open_sides(self) -> tuple[bool, bool, bool, bool]:
        """(left, top, right, bottom): the string is planned to leave the frame there (a tile only)."""
        if self.string_box is None or not self.tiled:
            return (False, False, False, False)
        x1, y1, x2, y2 = self.string_box
        mx, my = OPEN_MARGIN * self.width, OPEN_MARGIN * self.height
        return (x1 < mx, y1 < my, x2 > self.width - mx, y2 > self.height - my)

    def in_frame(self) -> tuple[float, float, float, float] | None:
        """The projected string's box widened by its rims (half the shed diameter at the GSD)
        and clipped to the frame: the region the string covers; None when it lies outside."""
        if self.string_box is None:
            return None
        rim = 0.5 * STRING_DIAMETER / (1e-3 * self.gsd_mm) if 0 < self.gsd_mm < math.inf else 0.0
        x1, y1, x2, y2 = self.string_box
        x1, y1, x2, y2 = x1 - rim, y1 - rim, x2 + rim, y2 + rim
        c = (max(0.0, x1), max(0.0, y1), min(float(self.width), x2), min(float(self.height), y2))
        return c if c[2] > c[0] and c[3] > c[1] else None


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
    T = np.asarray(T_c_w, dtype=np.float64)
    ends = np.linspace(-0.5, 0.5, STRING_SAMPLES)[:, None] * length * u + c  # distortion bends it
    pts = np.vstack([np.asarray(target, dtype=np.float64).reshape(1, 3), ends])
    uv, _ = ir.project_points(pts, T, camera)
    target_px = (float(uv[0, 0]), float(uv[0, 1])) if np.all(np.isfinite(uv[0])) else None
    geometry = photo_quality(camera, T, c, u, length=length)
    w, h = int(camera.width), int(camera.height)
    if not np.all(np.isfinite(uv[1:])):  # NaN: a point behind the camera
        return ExpectedView(target_px, None, w, h, float(required_span), bool(tiled), (), math.inf, False)
    lo, hi = uv[1:].min(axis=0), uv[1:].max(axis=0)
    box = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    span = float(np.max(uv[1:].max(axis=0) - uv[1:].min(axis=0))) / max(w, h)
    min_span = min(float(required_span), PLANNED_SHARE * span)
    samples = tuple((float(a), float(b)) for a, b in uv[1:])
    return ExpectedView(target_px, box, w, h, min_span, bool(tiled), samples, float(geometry.gsd_mm_px),
                        bool(geometry.whole_in_frame))


@dataclass(frozen=True)
class PhotoCheck:
    """The figures measured on one photo and its verdict (module docstring). ``box``: the
    detector's boxes in the projected string's corridor united, (x1, y1, x2, y2, best score) in
    the photo's pixels, None when none; ``detections``: boxes the detector gave; ``span_share``:
    the projected string's part in the frame over the frame's long side; ``offset``: (dx, dy) of
    that part's centre from the image centre over the width and height (None on an open axis);
    ``coverage``: the share of the projected string the boxes cover (:data:`MIN_COVERAGE`);
    ``gsd_mm``: mm/px at the string's far end; ``blur_extent``: see :data:`MAX_BLUR_EXTENT`
    (the verdict's); ``sharpness``: the Laplacian variance of the same region (:func:`sharpness`);
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
    coverage: float | None = None
    blur_extent: float | None = None
    gsd_mm: float | None = None

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


def _crop_grey(image: np.ndarray, box: tuple[float, float, float, float] | None) -> np.ndarray:
    h, w = image.shape[:2]
    if box is not None:
        x1, y1 = max(0, int(math.floor(box[0]))), max(0, int(math.floor(box[1])))
        x2, y2 = min(w, int(math.ceil(box[2]))), min(h, int(math.ceil(box[3])))
        image = image[y1:y2, x1:x2]
    if image.ndim == 2 or image.shape[0] < 3 or image.shape[1] < 3:
        return image
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY)


def sharpness(image: np.ndarray, box: tuple[float, float, float, float] | None = None) -> float:
    """The variance of the 3x3 Laplacian of ``image`` (BGR or grey uint8) inside ``box`` (pixels;
    None: the whole image), the crop first shrunk (area-averaged) to at most
    :data:`ANALYSIS_PX` along its longer side. 0 for a crop under 3x3 pixels. A figure for the
    record: the verdict is :func:`blur_extent`'s."""
    grey = _crop_grey(image, box)
    if grey.shape[0] < 3 or grey.shape[1] < 3:
        return 0.0
    k = ANALYSIS_PX / max(grey.shape[:2])
    if k < 1.0:
        grey = cv2.resize(grey, (max(3, round(grey.shape[1] * k)), max(3, round(grey.shape[0] * k))),
                          interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(grey, cv2.CV_64F, ksize=1).var())


def blur_extent(image: np.ndarray, box: tuple[float, float, float, float] | None = None) -> float:
    """The no-reference blur of ``image`` (BGR or grey uint8) inside ``box`` (pixels; None: the
    whole image) at the photo's own pixels, after Crete-Roffet, Dolmiere, Ladret, Nicolas, "The
    blur effect" (SPIE 2007): per direction, the share of the neighbour differences a further
    REBLUR_PX box blur leaves (a sharp edge loses most, a blurred one little); the worse of rows
    and columns (a motion blur smears one direction). 1 for a flat crop or one under 3x3 pixels."""
    grey = _crop_grey(image, box)
    if grey.shape[0] < 3 or grey.shape[1] < 3:
        return 1.0
    f = grey.astype(np.float64)
    worst = 0.0
    for ksize, axis in (((REBLUR_PX, 1), 1), ((1, REBLUR_PX), 0)):
        d_f = np.abs(np.diff(f, axis=axis))
        d_b = np.abs(np.diff(cv2.blur(f, ksize), axis=axis))
        total = float(d_f.sum())
        if total <= 0.0:
            return 1.0
        worst = max(worst, (total - float(np.maximum(0.0, d_f - d_b).sum())) / total)
    return worst


def _in_corridor(boxes: np.ndarray, view: ExpectedView) -> np.ndarray:
    """The boxes that meet the projected string's box widened by MAX_OFFSET of the frame."""
    if view.string_box is None or len(boxes) == 0:
        return boxes[:0]
    mx, my = MAX_OFFSET * view.width, MAX_OFFSET * view.height
    x1, y1, x2, y2 = view.string_box
    meets = (boxes[:, 0] <= x2 + mx) & (boxes[:, 2] >= x1 - mx) & (boxes[:, 1] <= y2 + my) & (boxes[:, 3] >= y1 - my)
    return boxes[meets]


def _united(part: np.ndarray) -> list[float] | None:
    """``part`` united (x1, y1, x2, y2, best score); None when empty."""
    if len(part) == 0:
        return None
    score = float(part[:, 4].max()) if part.shape[1] > 4 else 1.0
    return [float(part[:, 0].min()), float(part[:, 1].min()), float(part[:, 2].max()), float(part[:, 3].max()), score]


def coverage(boxes: np.ndarray, view: ExpectedView, image: np.ndarray | None = None) -> float:
    """The share of the projected string's samples inside the frame from the first to the last
    that lies in a box of ``boxes`` ((M, 4|5) pixels) widened by COVER_TOLERANCE of the long side
    or, given the photo ``image``, shows the string's shed pattern learned from the boxed samples
    (:func:`~insulator_rs.perception.shed_pattern.shed_evidence`: the network's boxes stop where
    the ground lies behind the sheds); 0 without samples in the frame or none in a box."""
    if not view.string_px:
        return 0.0
    uv = np.asarray(view.string_px, dtype=np.float64)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < view.width) & (uv[:, 1] >= 0) & (uv[:, 1] < view.height)
    if not inside.any() or len(boxes) == 0:
        return 0.0
    tol = COVER_TOLERANCE * max(view.width, view.height)
    b = boxes[:, :4]
    hit = ((uv[:, None, 0] >= b[None, :, 0] - tol) & (uv[:, None, 0] <= b[None, :, 2] + tol)
           & (uv[:, None, 1] >= b[None, :, 1] - tol) & (uv[:, None, 1] <= b[None, :, 3] + tol))
    hit = np.asarray(hit.any(axis=1), dtype=bool) & inside
    if not hit.any():
        return 0.0
    if image is not None and not hit[inside].all() and 0 < view.gsd_mm < math.inf:
        hit = _with_shed_evidence(image, uv, hit, STRING_DIAMETER / (1e-3 * view.gsd_mm)) & inside
    hit = hit[inside]
    # end to end: a shed the network missed between two it boxed is still the string where planned
    idx = np.flatnonzero(hit)
    return float((idx[-1] - idx[0] + 1) / hit.shape[0])


def _with_shed_evidence(image: np.ndarray, uv: np.ndarray, boxed: np.ndarray, diameter_px: float) -> np.ndarray:
    """:func:`~insulator_rs.perception.shed_pattern.shed_evidence` on the grey crop around the
    projected string (the strip and its windows reach at most 2 diameters past it): a bounded
    cost on a 12 MP photo."""
    margin = 2.0 * (1.0 + PERIOD_RANGE[1] * WINDOW_PERIODS) * diameter_px
    h, w = image.shape[:2]
    x1, y1 = (max(0, int(math.floor(float(uv[:, k].min()) - margin))) for k in (0, 1))
    x2, y2 = min(w, int(math.ceil(float(uv[:, 0].max()) + margin)) + 1), min(h, int(math.ceil(float(uv[:, 1].max()) + margin)) + 1)
    if x2 - x1 < 3 or y2 - y1 < 3:
        return boxed
    grey = _crop_grey(image, (x1, y1, x2, y2)).astype(np.float32)
    return shed_evidence(grey, uv - np.array([x1, y1]), boxed, diameter_px)


def _framing(view: ExpectedView) -> tuple[list[Reason], list[str], float, list[float | None]]:
    """The framing's reasons, cut sides, span share and offset, from the projection alone."""
    clip = view.in_frame()
    if view.string_box is None or clip is None:
        return [Reason.NOT_IN_VIEW], [], 0.0, [None, None]
    w, h = view.width, view.height
    reasons: list[Reason] = []
    x1, y1, x2, y2 = view.string_box
    mx, my = max(BORDER_MARGIN_PX, BORDER_MARGIN * w), max(BORDER_MARGIN_PX, BORDER_MARGIN * h)
    touches = (x1 <= mx, y1 <= my, x2 >= w - mx, y2 >= h - my)
    is_open = view.open_sides()
    cut = [n for n, t, o in zip(("left", "top", "right", "bottom"), touches, is_open) if t and not o]
    if cut or (not view.tiled and not view.whole):
        reasons.append(Reason.CUT)
    uv = np.asarray(view.string_px, dtype=np.float64)
    lo = np.clip(uv.min(axis=0), 0, [w, h])
    hi = np.clip(uv.max(axis=0), 0, [w, h])
    span = float(np.max(hi - lo)) / max(w, h)
    if span < view.min_span:
        reasons.append(Reason.TOO_SMALL)
    cx, cy = 0.5 * (clip[0] + clip[2]), 0.5 * (clip[1] + clip[3])
    off_x = None if (is_open[0] or is_open[2]) else (cx - 0.5 * w) / w
    off_y = None if (is_open[1] or is_open[3]) else (cy - 0.5 * h) / h
    if any(o is not None and abs(o) > MAX_OFFSET for o in (off_x, off_y)):
        reasons.append(Reason.OFF_CENTRE)
    return reasons, cut, span, [off_x, off_y]


def check_boxes(image: np.ndarray, boxes: np.ndarray, view: ExpectedView) -> PhotoCheck:
    """Judge ``image`` from the detector's ``boxes`` on it ((M, 4|5) pixels) against ``view``."""
    t0 = time.perf_counter()
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, boxes.shape[1] if np.ndim(boxes) == 2 else 5)
    h, w = image.shape[:2]
    if (w, h) != (view.width, view.height):
        raise ValueError(f"image: {w}x{h} px, the view was projected for {view.width}x{view.height}")
    reasons, cut, span, offset = _framing(view)
    cover, sharp, blur = None, None, None
    clip = view.in_frame()
    part = _in_corridor(b, view)
    if clip is not None:
        cover = coverage(b, view, image)
        if len(b) == 0:
            reasons.append(Reason.NOT_DETECTED)
        elif cover < MIN_COVERAGE:
            reasons.append(Reason.NOT_WHERE_PLANNED)
        sharp = sharpness(image, clip)
        blur = blur_extent(image, clip)
        if blur > MAX_BLUR_EXTENT:
            reasons.append(Reason.NOT_SHARP)
    verdict = PhotoVerdict.unfit(reasons) if reasons else PhotoVerdict.passed()
    return PhotoCheck(verdict, box=_united(part), detections=len(b),
                      cut_sides=cut, span_share=span, min_span=view.min_span, offset=offset, sharpness=sharp,
                      coverage=cover, blur_extent=blur, gsd_mm=view.gsd_mm, check_s=time.perf_counter() - t0)


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
    try:
        check = check_boxes(image, boxes, view)
    except ValueError as exc:  # an image not of the camera the view was projected for: unfit, said
        return PhotoCheck(PhotoVerdict.unfit([Reason.DETECTOR_ERROR], str(exc)), min_span=view.min_span,
                          error=str(exc), detect_s=detect_s)
    return replace(check, detect_s=detect_s)
