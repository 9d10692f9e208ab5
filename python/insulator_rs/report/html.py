"""``report.html``: the report a line crew opens in a browser, offline.

One self-contained page, written into the report folder from the folder's own files
(``summary.json``, ``inspection.geojson``, ``images/``), so it works on a flight's report and on
a replay's alike (``insulator-rs report DIR`` rewrites it):

* a summary at the top: status, flight time, insulators found / inspected / with a fit photo /
  skipped (with the reasons), photos and how many are fit for inspection, and which insulators
  have no fit photo and why (a replay, which takes no photos, says so);
* a map of the tower drawn as inline SVG from the GeoJSON (no tile server, no script): a top
  view and a side view across the line, with the flown path, the photo positions (with their
  heading) and the insulators (each a link to its section);
* per insulator: WGS-84 position, side, observations, what the LiDAR's geometry says of it (the
  LiDAR cue's evidence, when the cue flew), and its photos as thumbnails (JPEG,
  embedded as ``data:`` URIs, so the page shows them even when copied alone) linking to the
  full photos in ``images/``, each with its verdict and the figures it was decided on.

Every verdict on the page is the one the flight decided and wrote into ``summary.json`` (each
photo's ``check.verdict``, :class:`~insulator_rs.perception.photo_verdict.PhotoVerdict`); the
page never judges a photo again, so it cannot disagree with the log or the scorer. The planned
figures (GSD, frame share, motion blur in the exposure, from
:mod:`~insulator_rs.perception.photo_quality`) are shown as figures, not as a second verdict.

The page is written from Jinja2 templates (``templates/``: ``report.html.j2``, its macros
``photo.html.j2`` and ``map.svg.j2``, the style sheet ``report.css``), autoescaped: this module
only reads the folder and computes what the templates show (map pixel positions, texts).

Nothing is fetched at viewing time: no external style sheet, font, script or image. A
missing ``summary.json`` or ``inspection.geojson``, or one that is not what a report writes,
raises :class:`~insulator_rs.exceptions.ReportError` naming the file; a missing or unreadable
photo is shown as such in the page (and listed in ``HtmlReport.problems``), never a traceback.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import jinja2
import numpy as np

from insulator_rs.exceptions import ReportError
from insulator_rs.perception.photo_verdict import PhotoVerdict, fit_tally, verdict_of_record
from insulator_rs.report.folder import write_atomic
from insulator_rs.report.run_status import RunOutcome

HTML_NAME = "report.html"
SUMMARY_NAME = "summary.json"
GEOJSON_NAME = "inspection.geojson"
THUMB_WIDTH = 320  # px: thumbnails are scaled down to this width (never up)
THUMB_QUALITY = 80  # JPEG quality of the embedded thumbnails
MAP_SIZE = 460  # px: each map panel is a square of this side
MAP_MARGIN = 28  # px inside a panel kept free of drawing (labels, scale bar)
TEMPLATES = "templates"  # the page's Jinja2 templates and style sheet, in this package
PAGE_TEMPLATE = "report.html.j2"
_EARTH_R = 6_378_137.0  # m: WGS-84 semi-major axis (the map is a few tens of metres: a local tangent plane)


@dataclass
class HtmlReport:
    """What :func:`write_report_html` wrote: the page and the problems it shows (missing photos)."""

    path: Path
    insulators: int
    photos: int
    problems: list[str] = field(default_factory=list)


# -- reading the folder --------------------------------------------------------------------


def _read_json(path: Path, what: str) -> Any:
    if not path.is_file():
        raise ReportError(f"{path}: no {what} in the report folder"
                          + ("" if path.parent.is_dir() else f" ({path.parent} is not a folder)"))
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ReportError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ReportError(f"{path}: cannot be read: {exc.strerror}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ReportError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def _check_summary(path: Path, s: Any) -> dict[str, Any]:
    if not isinstance(s, dict):
        raise ReportError(f"{path}: expected a JSON object (an insulator_rs summary), got {type(s).__name__}")
    for key in ("insulators", "photos"):
        if not isinstance(s.get(key, []), list):
            raise ReportError(f"{path}: {key}: expected a list, got {type(s[key]).__name__}")
    for k, ins in enumerate(s.get("insulators", [])):
        if not isinstance(ins, dict) or "id" not in ins:
            raise ReportError(f"{path}: insulators[{k}]: expected an object with an id")
        geo = ins.get("wgs84")
        if not (isinstance(geo, dict) and all(_number(geo.get(c)) is not None for c in ("lat", "lon", "alt"))):
            raise ReportError(f"{path}: insulators[{k}] (id {ins.get('id')}): wgs84 lat/lon/alt missing or not numbers")
    for k, ph in enumerate(s.get("photos", [])):
        if not isinstance(ph, dict) or not isinstance(ph.get("file"), str):
            raise ReportError(f"{path}: photos[{k}]: expected an object with a file name")
    return s


def _check_geojson(path: Path, doc: Any) -> list[dict[str, Any]]:
    if not (isinstance(doc, dict) and doc.get("type") == "FeatureCollection" and isinstance(doc.get("features"), list)):
        raise ReportError(f"{path}: expected a GeoJSON FeatureCollection")
    features = []
    for k, f in enumerate(doc["features"]):
        try:
            kind = f["properties"]["kind"]
            gtype = f["geometry"]["type"]
            coords = np.asarray(f["geometry"]["coordinates"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise ReportError(f"{path}: features[{k}]: expected a Feature with a geometry and properties.kind") from None
        want = (3,) if gtype == "Point" else (None, 3)
        if gtype not in ("Point", "LineString") or coords.ndim != len(want) or coords.shape[-1] != 3 \
                or not np.all(np.isfinite(coords)):
            raise ReportError(f"{path}: features[{k}] ({kind}): expected a Point or LineString of finite "
                              f"(lon, lat, alt) positions")
        features.append({"kind": kind, "type": gtype, "coords": coords.reshape(-1, 3), "properties": f["properties"]})
    if not any(f["kind"] == "tower_base" for f in features):
        raise ReportError(f"{path}: no tower_base point (the map's origin)")
    return features


# -- the map ---------------------------------------------------------------------------------


def _local(coords: np.ndarray, base: np.ndarray) -> np.ndarray:
    """(N, 3) lon, lat, alt -> (N, 3) east, north, up in m about ``base`` (a local tangent
    plane: over the few tens of metres of a tower, mm-close to the report's own ENU)."""
    lat0 = math.radians(base[1])
    e = np.radians(coords[:, 0] - base[0]) * _EARTH_R * math.cos(lat0)
    n = np.radians(coords[:, 1] - base[1]) * _EARTH_R
    return np.stack([e, n, coords[:, 2] - base[2]], axis=1)


def _nice_length(span: float) -> float:
    """A round scale-bar length near a fifth of ``span`` (1, 2 or 5 times a power of ten)."""
    target = max(span / 5.0, 1e-3)
    p = 10 ** math.floor(math.log10(target))
    return min((m * p for m in (1, 2, 5, 10)), key=lambda v: abs(v - target))


class _Panel:
    """One map panel: world (a, b) in metres -> SVG pixels, equal scale on both axes."""

    def __init__(self, pts: np.ndarray) -> None:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        span = max(float(np.max(hi - lo)), 2.0)
        self.scale = (MAP_SIZE - 2 * MAP_MARGIN) / span
        self.center = 0.5 * (lo + hi)
        self.span = span

    def xy(self, a: float, b: float) -> tuple[str, str]:
        """SVG pixel coordinates of world (a, b), as written (0.1 px)."""
        return (f"{MAP_SIZE / 2 + (a - self.center[0]) * self.scale:.1f}",
                f"{MAP_SIZE / 2 - (b - self.center[1]) * self.scale:.1f}")


def _map_panel(title: str, axes: tuple[str, str], pts_by_kind: dict[str, np.ndarray], path: np.ndarray,
               insulators: list[dict[str, Any]], photos: list[dict[str, Any]], headings: list[np.ndarray | None],
               *, north_arrow: bool) -> dict[str, Any]:
    """What ``map.svg.j2`` draws of one panel: every mark's pixel position."""
    everything = [p for p in (path, *pts_by_kind.values()) if len(p)]
    panel = _Panel(np.vstack(everything)[:, :2])
    out: dict[str, Any] = {"title": title, "axes": axes, "north_arrow": north_arrow, "towers": [], "photos": [],
                           "insulators": [], "labels": []}
    out["path"] = " ".join(",".join(panel.xy(a, b)) for a, b in path[:, :2]) if len(path) >= 2 else ""
    for a, b in pts_by_kind.get("tower_base", np.zeros((0, 2)))[:, :2]:
        x, y = panel.xy(a, b)
        out["towers"].append({"x": f"{float(x) - 5:.1f}", "y": f"{float(y) - 5:.1f}"})
    for ph, (a, b), head in zip(photos, pts_by_kind.get("photo", np.zeros((0, 2))), headings):
        x, y = panel.xy(a, b)
        out["photos"].append({"x": x, "y": y, "file": ph["file"], "anchor": ph["anchor"],
                              "head": None if head is None else panel.xy(a + head[0], b + head[1])})
    labels: list[tuple[float, float, list[str]]] = []  # markers closer than 16 px share one label
    for ins, (a, b) in zip(insulators, pts_by_kind.get("insulator", np.zeros((0, 2)))):
        x, y = panel.xy(a, b)
        out["insulators"].append({"id": ins["id"], "x": x, "y": y, "color": _VERDICT_STYLE[ins["state"]][0]})
        fx, fy = float(x), float(y)
        near = next((lab for lab in labels if math.hypot(lab[0] - fx, lab[1] - fy) < 16.0), None)
        if near is None:
            labels.append((fx, fy, [str(ins["id"])]))
        else:
            near[2].append(str(ins["id"]))
    out["labels"] = [{"x": f"{x + 8:.1f}", "y": f"{y - 6:.1f}", "text": ", ".join(ids)} for x, y, ids in labels]
    bar = _nice_length(panel.span)
    out["bar_end"] = f"{12 + bar * panel.scale:.1f}"
    out["bar_label"] = f"{bar:g} m"
    return out


def _anchor(photo: Mapping[str, Any]) -> str:
    return "photo-" + "".join(c if c.isalnum() else "-" for c in Path(str(photo["file"])).stem)


# -- photos ----------------------------------------------------------------------------------


def _thumbnail(path: Path) -> tuple[str | None, tuple[int, int] | None, str | None]:
    """(data URI of a JPEG thumbnail, full (width, height), problem) of one photo."""
    import cv2

    if not path.is_file():
        return None, None, "file missing"
    try:
        data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
    except OSError as exc:
        return None, None, f"cannot be read: {exc.strerror}"
    size = _jpeg_size(data)
    # a JPEG decodes at 1/2, 1/4 or 1/8 of its size for the cost of that size: the smallest that
    # still gives the thumbnail's width (a 12 MP photo: 1/8, ~60x less work than all of it)
    factor = max((f for f in (1, 2, 4, 8) if size is not None and size[0] >= f * THUMB_WIDTH), default=1)
    flag = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4,
            8: cv2.IMREAD_REDUCED_COLOR_8}[factor]
    image = cv2.imdecode(data, flag) if len(data) else None
    if image is None or image.size == 0:
        return None, None, "not a decodable image"
    w, h = size or (factor * image.shape[1], factor * image.shape[0])
    if image.shape[1] > THUMB_WIDTH:
        image = cv2.resize(image, (THUMB_WIDTH, max(1, round(image.shape[0] * THUMB_WIDTH / image.shape[1]))),
                           interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, THUMB_QUALITY])
    if not ok:
        return None, (w, h), "could not be scaled down"
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii"), (w, h), None


def _jpeg_size(data: np.ndarray) -> tuple[int, int] | None:
    """(width, height) from a JPEG's start-of-frame marker; None when it has none (not a JPEG)."""
    b = data.tobytes()
    i = 2
    while i + 9 < len(b) and b[0:2] == b"\xff\xd8":
        if b[i] != 0xFF:
            return None
        marker, length = b[i + 1], int.from_bytes(b[i + 2:i + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return int.from_bytes(b[i + 7:i + 9], "big"), int.from_bytes(b[i + 5:i + 7], "big")
        i += 2 + length
    return None


def _verdict(p: Mapping[str, Any]) -> PhotoVerdict | None:
    """The verdict the flight decided for photo ``p`` (None: not checked); ReportError on a
    record that holds no readable one."""
    try:
        return verdict_of_record(p)
    except ValueError as exc:
        raise ReportError(f"{SUMMARY_NAME}: {exc}") from None


def _pct(v: Any) -> str:
    x = _number(v)
    return "–" if x is None else f"{100 * x:.1f} %"


def _num(v: Any, fmt: str = ".2f", unit: str = "") -> str:
    x = _number(v)
    return "–" if x is None else f"{x:{fmt}}{unit}"


def _latlon(lat: float, lon: float) -> str:
    return f"{abs(lat):.7f}° {'N' if lat >= 0 else 'S'}, {abs(lon):.7f}° {'E' if lon >= 0 else 'W'}"


def _yes(v: Any) -> str:
    return "–" if v is None else ("yes" if v else "no")


def _lidar_cue_fact(cue: Any, looks: Any) -> str | None:
    """The LiDAR cue in one line (summary.json ``lidar_cue``; None: a flight without the field)."""
    if not isinstance(cue, dict):
        return None
    if not cue.get("enabled"):
        return "off"
    lidar_looks = [lk for lk in (looks or []) if isinstance(lk, dict) and lk.get("source") == "lidar string"]
    held = sum(1 for e in cue.get("evidence", []) if e.get("held"))
    return (f"on: {len(cue.get('strings', []))} strings in {cue.get('cloud_points', 0)} returns near the tower; "
            f"{len(lidar_looks)} looks at strings only the LiDAR found "
            f"({sum(1 for lk in lidar_looks if lk.get('confirmed'))} confirmed by the camera); "
            f"{held} camera finds held for more evidence")


def _lidar_evidence(cue: Any, insulator_id: Any) -> str:
    """What the LiDAR's geometry says of a confirmed insulator (its row of ``lidar_cue.evidence``)."""
    if not isinstance(cue, dict) or not cue.get("enabled"):
        return "–"
    row = next((e for e in cue.get("evidence", []) if e.get("insulator_id") == insulator_id), None)
    if row is None:
        return "–"
    text = str(row.get("lidar"))
    if row.get("lidar") == "string":
        text += f", {_num(row.get('lidar_distance_m'))} m off (score {_num(row.get('lidar_score'), '.1f')})"
    if row.get("held"):
        text += f"; held for {row['held']} more localizations"
    return text


def _battery_fact(battery: Any, abort: Any) -> str | None:
    """The battery line: the charge at take-off and last, the reserve, what an early return left
    (summary.json ``battery``, ``abort.left``); None for a summary without one."""
    if not isinstance(battery, dict):
        return None
    if not battery.get("known"):
        return str(battery.get("note") or "no charge reported")
    text = (f"{_num(battery.get('fraction_at_takeoff'), '.0%')} at take-off, {_num(battery.get('fraction_last'), '.1%')}"
            f" last (reserve {_num(battery.get('reserve'), '.0%')})")
    left = abort.get("left") if isinstance(abort, dict) and battery.get("reason") else None
    if isinstance(left, dict):
        text += (f"; came back early, leaving {len(left.get('insulators_uninspected') or [])} insulators "
                 f"uninspected, {left.get('inspection_waypoints', 0)} inspection waypoints and "
                 f"{_num(left.get('exploration_left_m'), '.0f', ' m')} of the exploration path")
    return text


def _status_class(status: str) -> str:
    try:
        return RunOutcome.parse(status).status.value
    except ValueError:  # a summary.json of another version, or hand-edited
        return "unknown"


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "–"
    m, s = divmod(seconds, 60.0)
    return f"{int(m)} min {s:04.1f} s" if m else f"{s:.1f} s"


# -- the page --------------------------------------------------------------------------------

#: Each insulator's state on the page: (map colour, heading text, CSS class, legend text).
_VERDICT_STYLE = {
    "fit": ("#1a9850", "fit photo", "fit", "insulator with a fit photo"),
    "unfit": ("#f28e2b", "no fit photo", "unfit", "photos, none fit"),
    "none": ("#d62728", "no photo", "unfit", "no photo"),
    "replay": ("#8c8c8c", "found (a replay takes no photos)", "none", "found in a replay (no photos)"),
}


def _insulator_state(has_fit_photo: bool, photos: int, replay: bool) -> str:
    if has_fit_photo:
        return "fit"
    if photos:
        return "unfit"
    return "replay" if replay else "none"


def _no_fit_why(ins: Mapping[str, Any], verdicts: list[PhotoVerdict | None], photos: list[Mapping[str, Any]],
                skipped: list[dict[str, Any]], replay: bool) -> str:
    """Why insulator ``ins`` has no fit photo, from its photos' verdicts (never empty)."""
    if not photos:
        why = ("found in a replay, which takes no photos" if replay
               else "not inspected" if not ins.get("inspected") else "no photo")
        return why + "".join(f"; skipped: {it.get('reason')}" for it in skipped if it.get("insulator_id") == ins["id"])
    counts: dict[str, int] = {}
    for v in verdicts:
        for text in (["not checked"] if v is None else v.unfit_reasons):
            counts[text] = counts.get(text, 0) + 1
    n = len(photos)
    why = f"{n} photo{'s' if n > 1 else ''}, none fit: " + ", ".join(f"{t} ({k}x)" for t, k in counts.items())
    details = sorted({v.detail for v in verdicts if v is not None and v.detail})
    why += "".join(f"; {d}" for d in details)
    gsd = [g for g in (_number((p.get("quality") or {}).get("gsd_mm_px")) for p in photos) if g is not None]
    if gsd:
        why += f"; the finest GSD {min(gsd):.1f} mm/px"
    return why


def _photo_view(folder: Path, ph: Mapping[str, Any], verdict: PhotoVerdict | None,
                report: HtmlReport) -> dict[str, Any]:
    """What ``photo.html.j2`` shows of one photo: the thumbnail, the verdict, the figures."""
    rel = str(ph["file"])
    thumb: str | None
    size: tuple[int, int] | None
    problem: str | None
    if Path(rel).is_absolute() or ".." in Path(rel).parts:
        thumb, size, problem = None, None, "outside the report folder"
    else:
        thumb, size, problem = _thumbnail(folder / rel)
    if thumb is None:
        report.problems.append(f"{rel}: {problem}")
    geo_v = ph.get("wgs84")
    geo: Mapping[str, Any] = geo_v if isinstance(geo_v, dict) else {}
    rows = [("time (UTC)", str(ph.get("time_utc", "–"))),
            ("from", f"{_num(geo.get('lat'), '.7f')}°, {_num(geo.get('lon'), '.7f')}°, {_num(geo.get('alt'), '.1f')} m"),
            ("heading / gimbal", f"{_num(ph.get('heading_deg'), '.1f', '°')} / "
                                 f"{_num(ph.get('gimbal_pitch_deg'), '.1f', '°')}")]
    q = ph.get("quality") if isinstance(ph.get("quality"), dict) else None
    if q is not None:  # the figures from the pose and the localized string (photo_quality.py)
        rows += [("GSD (planned figure)", _num(q.get("gsd_mm_px"), ".2f", " mm/px")),
                 ("span / area of frame (planned)", f"{_pct(q.get('span_share'))} / {_pct(q.get('frame_share'))}"),
                 ("motion blur in the exposure", _num(q.get("motion_blur_px"), ".2f", " px"))]
    c = ph.get("check") if isinstance(ph.get("check"), dict) else None
    if c is not None:  # the figures measured on the photo, that the verdict was decided on
        off = [f"{100 * float(o):+.1f} %" if _number(o) is not None else "open" for o in c.get("offset") or []]
        rows += [("attempt", str(ph.get("attempt", 1))),
                 ("detected span / offset", f"{_pct(c.get('span_share'))} (needs {_pct(c.get('min_span'))}) / "
                                            + (", ".join(off) or "–")),
                 ("sharpness (Laplacian variance)", _num(c.get("sharpness"), ".0f"))]
    if verdict is None:
        text, css, code = "not checked on the photo: no verdict", "none", "none"
    else:
        text, css, code = ("fit for inspection" if verdict.fit else f"not fit: {verdict.describe()[len('unfit: '):]}",
                           "fit" if verdict.fit else "unfit", verdict.fitness.value)
    return {"file": rel, "href": quote(rel), "anchor": _anchor(ph), "thumb": thumb, "problem": problem or "",
            "size": f"{size[0]}×{size[1]} px" if size else None, "rows": rows,
            "verdict_text": text, "verdict_class": css, "verdict_code": code}


def _environment() -> jinja2.Environment:
    return jinja2.Environment(loader=jinja2.PackageLoader("insulator_rs.report", TEMPLATES),
                              autoescape=True, undefined=jinja2.StrictUndefined,
                              trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)


def render_report_html(folder: Path) -> tuple[str, HtmlReport]:
    """The page of the report in ``folder`` and what it holds; raises ReportError (see the module)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ReportError(f"{folder}: no such report folder")
    summary_path = folder / SUMMARY_NAME
    s = _check_summary(summary_path, _read_json(summary_path, "summary.json"))
    geo_path = folder / GEOJSON_NAME
    features = _check_geojson(geo_path, _read_json(geo_path, "inspection.geojson"))
    base = next(f for f in features if f["kind"] == "tower_base")["coords"][0]
    insulators: list[dict[str, Any]] = [dict(i) for i in s.get("insulators", [])]
    photos: list[dict[str, Any]] = [dict(p) for p in s.get("photos", [])]
    report = HtmlReport(folder / HTML_NAME, len(insulators), len(photos))
    replay = s.get("run") == "replay"
    verdicts = {id(p): _verdict(p) for p in photos}
    fit_photos, with_fit = fit_tally(photos)

    # each insulator's state, read off its photos' verdicts: a fit photo, photos but none fit, none
    by_ins: dict[Any, list[dict[str, Any]]] = {}
    for ph in photos:
        by_ins.setdefault(ph.get("insulator_id"), []).append(ph)
    for ins in insulators:
        ins["_photos"] = by_ins.get(ins["id"], [])
        ins["state"] = _insulator_state(ins["id"] in with_fit, len(ins["_photos"]), replay)

    # the map from the GeoJSON: points in the order the writer puts them, matched by kind
    pts = {k: _local(np.vstack([f["coords"] for f in features if f["kind"] == k and f["type"] == "Point"]), base)
           for k in ("tower_base", "insulator", "photo") if any(f["kind"] == k for f in features)}
    line = [f for f in features if f["kind"] == "flight_path" and f["type"] == "LineString"]
    path = _local(line[0]["coords"], base) if line else np.zeros((0, 3))
    geo_ins = [f["properties"].get("id") for f in features if f["kind"] == "insulator"]
    geo_photos = [f["properties"] for f in features if f["kind"] == "photo"]
    map_ins = [next((i for i in insulators if i["id"] == gid), {"id": gid, "state": "none"}) for gid in geo_ins]
    map_photos = [{"file": str(p.get("file", "photo")), "anchor": _anchor({"file": p.get("file", "photo")})}
                  for p in geo_photos]
    headings = []
    for p in geo_photos:
        h = _number(p.get("heading_deg"))
        headings.append(None if h is None else 1.5 * np.array([math.sin(math.radians(h)), math.cos(math.radians(h))]))
    top = {k: v[:, :2] for k, v in pts.items()}
    # side view: horizontal axis across the line = the insulators' main horizontal spread (the cross-arms)
    spread = pts.get("insulator", np.zeros((0, 3)))[:, :2]
    if len(spread) < 2:
        spread = path[:, :2] if len(path) >= 2 else np.array([[0.0, 0.0], [1.0, 0.0]])
    _, _, vt = np.linalg.svd(spread - spread.mean(axis=0), full_matrices=False)
    across = vt[0] if np.all(np.isfinite(vt[0])) else np.array([1.0, 0.0])

    def side(v: np.ndarray) -> np.ndarray:
        return np.stack([v[:, :2] @ across, v[:, 2]], axis=1)

    side_pts = {k: side(v) for k, v in pts.items()}
    side_heads = [None if h is None else np.array([h[:2] @ across, 0.0]) for h in headings]
    panels = [_map_panel("top view", ("east", "north"), top, path[:, :2], map_ins, map_photos, headings,
                         north_arrow=True),
              _map_panel("side view (across the line)", ("across", "up"), side_pts, side(path) if len(path) else path,
                         map_ins, map_photos, side_heads, north_arrow=False)]

    # the summary
    status = str(s.get("status", "unknown"))
    skipped = [it if isinstance(it, dict) else {"reason": str(it)} for it in s.get("inspections_skipped") or []]
    checks_v = s.get("photo_checks")
    checks: dict[str, Any] = checks_v if isinstance(checks_v, dict) else {}
    cards = [("found", len(insulators), "insulators found"),
             ("inspected", sum(1 for i in insulators if i.get("inspected")), "insulators inspected"),
             ("with-fit-photo", sum(1 for i in insulators if i["state"] == "fit"), "insulators with a fit photo"),
             ("skipped", len(skipped), "inspections skipped"),
             ("photos", len(photos), "photos" if photos or not replay else "photos (a replay takes none)"),
             ("fit", fit_photos, "photos fit for inspection"),
             ("retakes", checks.get("retakes", 0), "photos retaken (checked unfit)"),
             ("flight-time", _duration(_number(s.get("flight_time_s"))), "flight time"),
             ("distance", _num(s.get("distance_m"), ".0f", " m"), "flown")]
    origin = s.get("origin") or {}
    facts: list[tuple[str, Any]] = [
        ("run", s.get("run")), ("recording", s.get("recording")), ("detector", s.get("detector")),
        ("localization", s.get("method")), ("vehicle", s.get("vehicle")), ("sensors", s.get("sensors")),
        ("tower base (WGS-84)", f"{_num(origin.get('lat'), '.7f')}°, {_num(origin.get('lon'), '.7f')}°, "
                                f"{_num(origin.get('alt'), '.1f', ' m')}" if origin else None)]
    fs = s.get("failsafe")
    if isinstance(fs, dict):
        facts.append(("failsafe", f"{fs.get('reason')}; action: {fs.get('action')}"))
    facts.append(("battery", _battery_fact(s.get("battery"), s.get("abort"))))
    facts.append(("LiDAR cue", _lidar_cue_fact(s.get("lidar_cue"), s.get("second_looks"))))
    no_fit = [{"id": ins["id"], "why": _no_fit_why(ins, [verdicts[id(p)] for p in ins["_photos"]], ins["_photos"],
                                                   skipped, replay)}
              for ins in insulators if ins["state"] != "fit"]

    def side_text(v: Any) -> str:
        return ("+ side of the line" if v == 1 else "− side of the line" if v == -1 else "–" if v is None else str(v))

    listed = {i["id"] for i in insulators}
    views = []
    for ins in insulators:
        g, c = ins["wgs84"], ins.get("center") or [None] * 3
        style = _VERDICT_STYLE[ins["state"]]
        views.append({"id": ins["id"], "verdict_text": style[1], "verdict_class": style[2],
                      "wgs84": f"{_latlon(g['lat'], g['lon'])}, {g['alt']:.2f} m",
                      "enu": f"{_num(c[0])}, {_num(c[1])}, {_num(c[2])} m", "side": side_text(ins.get("side")),
                      "observations": str(ins.get("observations", "–")), "inspected": _yes(ins.get("inspected")),
                      "lidar": _lidar_evidence(s.get("lidar_cue"), ins["id"]),
                      "photos": [_photo_view(folder, p, verdicts[id(p)], report) for p in ins["_photos"]]})
    others = [_photo_view(folder, p, verdicts[id(p)], report) for p in photos if p.get("insulator_id") not in listed]
    # a flight's legend has its three states; a replay's the ones its insulators are in
    shown = {i["state"] for i in insulators} if replay else {"fit", "unfit", "none"}
    legend = [(style[0], style[3]) for key, style in _VERDICT_STYLE.items() if key in shown]
    page = _environment().get_template(PAGE_TEMPLATE).render(
        title=f"Insulator inspection — {s.get('scene') or Path(str(s.get('mission') or folder.name)).stem}",
        folder_name=folder.name, started_utc=str(s.get("started_utc", "–")), mission=str(s.get("mission", "–")),
        status=status, status_class=_status_class(status), replay=replay, photos=photos,
        cards=[{"key": k, "value": str(v), "label": label} for k, v, label in cards],
        facts=[(k, str(v)) for k, v in facts if v is not None], skipped=skipped, no_fit=no_fit,
        panels=panels, map_size=MAP_SIZE, legend=legend, insulators=views, other_photos=others,
        problems=report.problems)
    return page, report


def write_report_html(folder: Path) -> HtmlReport:
    """Write ``report.html`` into the report ``folder`` atomically (a kill leaves the old page or the
    new one); raises ReportError for a folder that is not a readable report (see the module)."""
    text, report = render_report_html(Path(folder))
    write_atomic(report.path, text)
    return report
