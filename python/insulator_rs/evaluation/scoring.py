"""The post-flight scorer: a flight's report against the scene it flew (ground truth).

Ground truth enters here and nowhere in the flight: the flight writes ``summary.json``
(what it knows), and this compares it with a simulator scene afterwards:

* each localized insulator is matched to the nearest true one: centre error (m) and axis
  error (deg); a true insulator counts as found when a localization lies within
  :data:`MATCH_DISTANCE` of it;
* each photo's true insulator (the one nearest the insulator it was taken for) is projected
  through the photo's own camera pose and intrinsics as the flight recorded them
  (:func:`~insulator_rs.evaluation.photo_coverage.string_in_photo_record`, the projection the
  coverage figures use too): is it in the picture, and whole? No render: a 12 MP photo costs
  a few hundred projected points, not a ray-cast image;
* each photo's verdict is read from the summary (the one the flight decided,
  :class:`~insulator_rs.perception.photo_verdict.PhotoVerdict`), never decided again here.

The result is ``score.json`` beside the summary.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.evaluation.photo_coverage import photo_coverage, string_in_photo_record
from insulator_rs.perception.photo_verdict import verdict_of_record
from insulator_rs.report.jsonfile import write_json
from insulator_rs.report.summary import RunSummary
from insulator_rs.sim.towers import InsulatorTruth, Tower

# m: a localized insulator this close to a true one counts as having found it.
MATCH_DISTANCE = 1.5


def _nearest(truth: list[InsulatorTruth], center: np.ndarray) -> tuple[InsulatorTruth, float]:
    d = [float(np.linalg.norm(t.center - center)) for t in truth]
    k = int(np.argmin(d))
    return truth[k], d[k]


def _axis_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = abs(float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(min(1.0, c)))


def score_tracks(tracks: list[dict[str, Any]], truth: list[InsulatorTruth]) -> list[dict[str, Any]]:
    """Each perception track of a summary (``tracks``) with its nearest true insulator: on one
    (``true_insulator``) when within MATCH_DISTANCE, else a track on something else (steel,
    a conductor): the per-track evidence the birth rule and the confirmations are judged on."""
    rows = []
    for t in tracks:
        row = dict(t)
        if truth:
            gt, d = _nearest(truth, np.asarray(t["center"], dtype=np.float64))
            row.update(gt_instance_id=gt.instance_id, distance_m=d, true_insulator=d < MATCH_DISTANCE)
        else:
            row.update(gt_instance_id=None, distance_m=None, true_insulator=False)
        rows.append(row)
    return rows


def score_flight(summary: RunSummary | dict[str, Any], tower: Tower, *,
                 progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Score a flight summary (as written to ``summary.json``) against ``tower``'s truth.
    ``progress``: told a line as each stage ends (the insulators, the photos, the coverage)."""
    t0 = time.perf_counter()

    def say(text: str) -> None:
        if progress is not None:
            progress(f"scoring: {text} ({time.perf_counter() - t0:.1f} s)")

    if isinstance(summary, RunSummary):
        summary = summary.as_dict()
    truth = list(tower.insulators)
    found = summary.get("insulators", [])
    rows: list[dict[str, Any]] = []
    centers: dict[int, np.ndarray] = {}
    for r in found:
        center = np.asarray(r["center"], dtype=np.float64)
        centers[int(r["id"])] = center
        if not truth:
            rows.append({"id": r["id"], "gt_instance_id": None, "error_m": None, "axis_error_deg": None})
            continue
        gt, err = _nearest(truth, center)
        rows.append({"id": r["id"], "gt_instance_id": gt.instance_id, "error_m": err,
                     "axis_error_deg": _axis_error_deg(gt.axis, np.asarray(r["axis"], dtype=np.float64)),
                     "inspected": bool(r.get("inspected"))})
    matched = {r["gt_instance_id"] for r in rows if r["error_m"] is not None and r["error_m"] < MATCH_DISTANCE}
    inspected = {r["gt_instance_id"] for r in rows
                 if r["error_m"] is not None and r["error_m"] < MATCH_DISTANCE and r.get("inspected")}
    errors = [r["error_m"] for r in rows if r["error_m"] is not None]
    say(f"{len(found)} insulators matched to {len(truth)} true ones")
    photo_rows = []
    default_camera = summary.get("photo_camera")
    by_id = {t.instance_id: t for t in truth}
    for p in summary.get("photos", []):
        photographed = centers.get(int(p["insulator_id"]))
        verdict = verdict_of_record(p)
        row: dict[str, Any] = {"file": p["file"], "insulator_id": p["insulator_id"], "gt_instance_id": None,
                               "insulator_visible": None, "insulator_whole_in_frame": None,
                               "verdict": None if verdict is None else verdict.to_json()}
        if photographed is not None and truth:
            gt, _ = _nearest(truth, photographed)
            row["gt_instance_id"] = gt.instance_id
            fig = string_in_photo_record(p, by_id[gt.instance_id], default_camera)
            if fig is not None:
                row["insulator_visible"] = fig["visible"] is not None
                row["insulator_whole_in_frame"] = fig["whole_in_frame"]
        photo_rows.append(row)
    say(f"{len(photo_rows)} photos: the true string projected through each one's pose")
    coverage = photo_coverage(summary, truth)
    say(f"coverage: {coverage['insulators_covered']} of {coverage['insulators_in_scene']} strings covered")
    return {
        "scene": tower.spec.name,
        "match_distance_m": MATCH_DISTANCE,
        "insulators_in_scene": len(truth),
        "insulators_found": len(found),
        "insulators_matched": len(matched),
        "insulators_inspected_matched": len(inspected),
        "mean_error_m": float(np.mean(errors)) if errors else None,
        "insulators": rows,
        "photos": photo_rows,
        "tracks": score_tracks(summary.get("tracks", []), truth),
        # every string covered by photos at >= 60 % of the long side and <= 2 mm/px? (from the truth)
        "photo_coverage": coverage,
        "ground_truth": [{"instance_id": t.instance_id, "center": t.center.tolist(), "axis": t.axis.tolist(),
                          "side": t.side} for t in truth],
    }


def write_score(folder: Path, score: dict[str, Any]) -> Path:
    """``score.json`` in the report folder (atomically, the package's one JSON writer)."""
    return write_json(Path(folder) / "score.json", score)
