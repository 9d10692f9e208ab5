"""Boxes of one string: a detector often boxes a string in parts, so its scale is judged on them together.

Measured on a live-sensor flight against PX4 SITL (the shipped ``insulator-sim`` network on the
320 x 240 detection frames, replayed from its recording): of the 66 boxes on the two true
strings, a frame held two or three boxes on the same string in most events (heights 20-25 px
beside 34-46 px for the whole string), and 23 of them were refused as ``implausible``: the
localized string, of the mission's length, spans the whole string in the image, so a box of a
part of it reads as a scale mismatch. The boxes are still handled one by one (each is an
event of its track); only the scale check looks at the union of a box's group.

Two boxes are parts of one string when both are elongated the same way (both taller than wide,
or both wider than tall: a suspension or a tension string) and they overlap across their
elongation by at least :data:`ACROSS_OVERLAP` of the narrower, and along it they overlap or
leave a gap of at most :data:`ALONG_GAP` of the shorter; groups are closed transitively.
"""

from __future__ import annotations

import numpy as np

# of the narrower box's width (tall boxes) or height (wide ones): side by side in one column
ACROSS_OVERLAP = 0.5
# of the shorter box's length along the elongation: a gap the detector leaves between parts
ALONG_GAP = 0.5


def _same_string(a: np.ndarray, b: np.ndarray) -> bool:
    wa, ha = a[2] - a[0], a[3] - a[1]
    wb, hb = b[2] - b[0], b[3] - b[1]
    if (ha >= wa) != (hb >= wb):
        return False
    across, along = (0, 1) if ha >= wa else (1, 0)  # the box coordinate across the elongation
    overlap = min(a[across + 2], b[across + 2]) - max(a[across], b[across])
    narrower = min(a[across + 2] - a[across], b[across + 2] - b[across])
    gap = max(a[along], b[along]) - min(a[along + 2], b[along + 2])
    shorter = min(a[along + 2] - a[along], b[along + 2] - b[along])
    return bool(overlap >= ACROSS_OVERLAP * narrower and gap <= ALONG_GAP * shorter)


def string_boxes(boxes: np.ndarray) -> np.ndarray:
    """For each of ``boxes`` (K, >= 4: x0, y0, x1, y1 px), the union (K, 4) of its group."""
    b = np.asarray(boxes, dtype=np.float64)[:, :4]
    group = list(range(len(b)))

    def root(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    for i in range(len(b)):
        for j in range(i + 1, len(b)):
            if _same_string(b[i], b[j]):
                group[root(j)] = root(i)
    roots = np.array([root(i) for i in range(len(b))], dtype=np.int64)
    out = b.copy()
    for r in np.unique(roots):
        members = roots == r
        out[members] = [b[members, 0].min(), b[members, 1].min(), b[members, 2].max(), b[members, 3].max()]
    return out
