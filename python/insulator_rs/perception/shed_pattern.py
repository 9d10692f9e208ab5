"""Does the photo show the string's sheds where the network gave no box? The photo check's second
image cue (:mod:`~insulator_rs.perception.photo_check`), for the stretches of the projected string
the close-up network leaves unboxed.

A string is a row of sheds at a steady pitch: along its axis the image repeats with that period;
sky, ground, a lattice member or a fitting beside the string's end does not. The cue learns the
period and the pattern's strength from the stretch the network *did* box (its evidence that the
string is there), then asks each unboxed stretch of the projection for the same repetition:

1. a strip of the photo along the projected axis (:func:`axis_profile`), one shed diameter wide,
   averaged across into a profile; its departure from a running median half a diameter long (the
   background: sky, then ground; the median follows a step in it where a mean would smear it),
   taken by size, not sign (a shed is darker than the sky and brighter than the ground);
2. the period: the lag, between 0.2 and 1.5 shed diameters, where the boxed stretch's profile
   best repeats (normalized autocorrelation); the cue is not used when even there the boxed
   stretch repeats less than :data:`MIN_REPEAT` (a string whose sheds do not show as a pattern);
3. outward from the boxed stretch, sample by sample, each unboxed sample of the projection holds
   the string while the profile within :data:`WINDOW_PERIODS` periods of it repeats at that
   period by at least :data:`MIN_CONTINUE` and its contrast keeps at least :data:`MIN_ENERGY_STEP`
   of the previous sample's (the first that does not ends the string there).

Why: on tower B's 12 MP close-ups the shipped network boxes the sheds against the sky and stops
where the ground is behind them (4 of 11 good photos "not where planned", retaken to the same
result); the repetition runs on through the ground (0.6-0.9 there), and stops where the string
does: a gimbal 2 degrees off in pitch leaves the projection's last samples at -0.2..0.1, a focal
0.8x the recorded both ends at -0.5..0.1 (``insulator-rs eval photo-check``).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.ndimage import median_filter

#: Normalized autocorrelation at the shed period that counts as the string's pattern (the boxed
#: stretch of a good 12 MP close-up repeats at 0.6-1.0; past the string's end -0.5..0.1).
MIN_REPEAT = 0.5
#: The repetition a window past the boxed stretch must keep to go on: lower than the learned
#: stretch's, since a member of the lattice behind the string or the conductor clamp at its end
#: shares the window (tower B's good close-ups: 0.2-0.4 over the lowest sheds, against the ground
#: with the tower's leg behind); a window with no string at its centre is refused by
#: :data:`MIN_ENERGY_STEP`.
MIN_CONTINUE = 0.3
#: Half-width of the window each sample is judged on, in shed periods (a window holds 2.5 periods:
#: enough pairs for a steady figure, short enough to end near where the string ends).
WINDOW_PERIODS = 1.25
#: Pairs (in periods) a window must hold inside the photo to judge a sample: a sample near the
#: border has half its window outside.
MIN_PAIRS_PERIODS = 0.5
#: The least share of the previous sample's pattern energy (mean square within half a period) a
#: sample may hold and still be the string: the sheds' contrast changes gradually along a string
#: (tower B's good close-ups: at most 2x from sample to sample, the sky behind giving way to the
#: ground) and falls at its end (to 0.0-0.2 of the last shed's); the repetition alone, being
#: normalized, counts a window whose last sheds sit at one edge as fully as one full of them.
MIN_ENERGY_STEP = 0.35
#: A string wider than this share of the photo's long side is too near for a row of sheds to show
#: (a close-up's is about a tenth): the cue adds nothing there.
MAX_DIAMETER_SHARE = 0.25
#: Lags searched for the period, in shed diameters (the projected string's width).
PERIOD_RANGE = (0.2, 1.5)
#: px: the strip's sampling step across the axis (the profile is a mean across: every 2nd pixel
#: gives the same mean at half the cost on a 12 MP photo).
ACROSS_STEP_PX = 2


def axis_profile(grey: np.ndarray, string_px: np.ndarray, diameter_px: float,
                 extend_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The profile along the polyline ``string_px`` ((N, 2) u, v) of ``grey`` (float32), 1 px a
    step, extended ``extend_px`` beyond both ends: the strip ``diameter_px`` wide averaged across,
    the size of its departure from its running median over half a diameter, less that size's own
    running median (NaN where the strip leaves the image); and each
    polyline point's position along the profile (px)."""
    uv = np.asarray(string_px, dtype=np.float64)
    seg = np.linalg.norm(np.diff(uv, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    length = float(arc[-1])
    ext = float(extend_px)
    h, w = grey.shape[:2]
    # only the stretch whose strip can meet the image: a string projected from near the camera's
    # plane runs millions of pixels out of the frame, and a strip along all of it would not fit
    # in memory
    first, last = _in_image(uv[0], uv[-1], w, h, margin=ext + diameter_px)
    if first is None or last is None:
        return np.full(0, np.nan), arc + ext
    lo = max(-ext, math.floor(first * length) - 1.0)
    hi = min(length + ext, math.ceil(last * length) + 1.0)
    if hi < lo:
        return np.full(0, np.nan), arc + ext
    t = np.arange(lo, hi + 1.0)
    head = (uv[1] - uv[0]) / max(seg[0], 1e-9)
    tail = (uv[-1] - uv[-2]) / max(seg[-1], 1e-9)
    cu = np.interp(t, arc, uv[:, 0])
    cv = np.interp(t, arc, uv[:, 1])
    before, after = t < 0, t > length  # beyond the ends: straight on along the end's direction
    cu[before], cv[before] = uv[0, 0] + t[before] * head[0], uv[0, 1] + t[before] * head[1]
    cu[after], cv[after] = uv[-1, 0] + (t[after] - length) * tail[0], uv[-1, 1] + (t[after] - length) * tail[1]
    d = uv[-1] - uv[0]
    d = d / max(float(np.linalg.norm(d)), 1e-9)
    normal = np.array([-d[1], d[0]])
    half = max(1, int(0.5 * diameter_px))
    offsets = np.arange(-half, half + 1, ACROSS_STEP_PX, dtype=np.float64)
    mx = (cu[:, None] + offsets[None, :] * normal[0]).astype(np.float32)
    my = (cv[:, None] + offsets[None, :] * normal[1]).astype(np.float32)
    inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
    strip = cv2.remap(grey, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    counted = inside.sum(axis=1)
    valid = counted >= 0.5 * len(offsets)
    profile = np.where(valid, (strip * inside).sum(axis=1) / np.maximum(counted, 1), 0.0)
    if not valid.any():
        return np.full(len(t), np.nan), arc - lo
    # the background's slow change (sky, then ground) taken away by a running median half a
    # diameter long (shorter than a period, longer than a shed's edge-on thickness): it follows a
    # step (a horizon, a member behind the string) where a moving mean would smear it over the
    # window and hide the sheds beside it; outside the image the nearest valid value stands in,
    # so the median is never pulled by the border
    size = max(3, int(0.5 * diameter_px) | 1)
    nearest = np.interp(np.arange(len(t)), np.flatnonzero(valid), profile[valid])
    # the sheds' contrast, whatever its sign (a shed is darker than the sky behind it and brighter
    # than the ground: the pattern must run on where the background changes), less its own level
    contrast = np.abs(nearest - median_filter(nearest, size=size, mode="nearest"))
    contrast -= median_filter(contrast, size=size, mode="nearest")
    return np.where(valid, contrast, np.nan), arc - lo


def _in_image(a: np.ndarray, b: np.ndarray, w: int, h: int, margin: float) -> tuple[float | None, float | None]:
    """The part of the line from ``a`` to ``b`` (pixels; parameter 0 at ``a``, 1 at ``b``, any
    value along the line beyond them) inside the image widened by ``margin`` on every side, as
    its first and last parameter (Liang-Barsky clipping); (None, None) where the line misses it."""
    d = b - a
    lo, hi = -math.inf, math.inf
    for p0, dp, low, high in ((a[0], d[0], -margin, w - 1 + margin), (a[1], d[1], -margin, h - 1 + margin)):
        if abs(dp) < 1e-12:
            if not low <= p0 <= high:
                return None, None
            continue
        t1, t2 = (low - p0) / dp, (high - p0) / dp
        lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
    return (lo, hi) if lo <= hi else (None, None)


def _repeat(x: np.ndarray, lag: int) -> tuple[float, int]:
    """The normalized autocorrelation of ``x`` at ``lag`` over its pairs with no NaN, and their
    count."""
    u, v = x[:-lag], x[lag:]
    ok = ~(np.isnan(u) | np.isnan(v))
    u, v = u[ok], v[ok]
    den = math.sqrt(float(np.dot(u, u)) * float(np.dot(v, v)))
    return (float(np.dot(u, v)) / den if den > 0 else 0.0), int(ok.sum())


def shed_evidence(grey: np.ndarray, string_px: np.ndarray, boxed: np.ndarray,
                  diameter_px: float) -> np.ndarray:
    """Which samples of the projected string ``string_px`` ((N, 2)) hold the string's shed
    pattern (module docstring), learned from the ``boxed`` samples ((N,) bool: in a network's
    box); ``diameter_px``: the string's width in the photo. All False when nothing is boxed or the
    boxed stretch shows no pattern. The boxed samples are returned as they are; between two boxed
    samples nothing is added (the coverage bridges those gaps itself)."""
    boxed = np.asarray(boxed, dtype=bool)
    out = boxed.copy()
    n = len(boxed)
    too_near = diameter_px > MAX_DIAMETER_SHARE * max(grey.shape[:2])  # no row of sheds to see
    if (n < 2 or not boxed.any() or boxed.all() or not (math.isfinite(diameter_px) and diameter_px >= 4)
            or too_near or not np.all(np.isfinite(string_px))):
        return out
    lags = np.arange(max(2, int(PERIOD_RANGE[0] * diameter_px)), int(PERIOD_RANGE[1] * diameter_px) + 1)
    reach = WINDOW_PERIODS * lags[-1]
    profile, at = axis_profile(grey, string_px, diameter_px, reach)
    if len(profile) <= lags[-1]:
        return out
    spacing = float(at[-1] - at[0]) / (n - 1)
    rows = np.arange(len(profile))
    in_boxed = np.zeros(len(profile), dtype=bool)
    for i in np.flatnonzero(boxed):
        in_boxed |= np.abs(rows - at[i]) <= 0.5 * spacing
    learned = np.where(in_boxed, profile, np.nan)
    repeats = [_repeat(learned, int(lag)) for lag in lags]
    best = int(np.argmax([r for r, _ in repeats]))
    period, strength = int(lags[best]), repeats[best][0]
    if strength < MIN_REPEAT:
        return out
    half = WINDOW_PERIODS * period

    def energy(i: int) -> float:
        """The pattern's mean square within half a period of sample ``i``."""
        part = profile[max(0, int(at[i] - 0.5 * period)):max(0, int(at[i] + 0.5 * period) + 1)]
        part = part[~np.isnan(part)]
        return float(np.mean(part * part)) if len(part) else 0.0

    def holds(i: int, before: float) -> bool:
        lo, hi = max(0, int(at[i] - half)), min(len(profile), int(at[i] + half) + 1)
        r, pairs = _repeat(profile[lo:hi], period) if hi - lo > period else (0.0, 0)
        return (pairs >= MIN_PAIRS_PERIODS * period and r >= MIN_CONTINUE
                and energy(i) >= MIN_ENERGY_STEP * before)

    # outward from the boxed stretch, sample by sample, while the pattern holds: the string goes
    # on from where the network saw it; a repetition apart from it (a lattice's bays) is not it
    boxed_at = np.flatnonzero(boxed)
    for step, start, stop in ((-1, int(boxed_at[0]) - 1, -1), (1, int(boxed_at[-1]) + 1, n)):
        before = energy(start - step)
        for k in range(start, stop, step):
            if not holds(k, before):
                break
            out[k], before = True, energy(k)
    return out
