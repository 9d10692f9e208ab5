"""``report.html``: the report a line crew opens in a browser, offline.

One self-contained page, written into the report folder from the folder's own files
(``summary.json``, ``inspection.geojson``, ``images/``), so it works on a flight's report and on
a replay's alike (``insulator-rs report DIR`` rewrites it):

* a summary at the top: status, flight time, insulators found / inspected / skipped (with the
  reasons), photos and how many are fit for inspection, and which insulators have no fit photo
  and why;
* a map of the tower drawn as inline SVG from the GeoJSON (no tile server, no script): a top
  view and a side view across the line, with the flown path, the photo positions (with their
  heading) and the insulators (each a link to its section);
* per insulator: WGS-84 position, side, observations, and its photos as thumbnails (JPEG,
  embedded as ``data:`` URIs, so the page shows them even when copied alone) linking to the
  full photos in ``images/``, with each photo's quality figures (GSD, frame share, whole,
  blur, fit for inspection) and its check on the photo itself (perception/photo_check.py: the
  attempt, the detected span and offset, the sharpness, the verdict; a retaken photo is listed
  with its retakes).

Nothing is fetched at viewing time: no external style sheet, font, script or image. A
missing ``summary.json`` or ``inspection.geojson``, or one that is not what a report writes,
raises :class:`~insulator_rs.exceptions.ReportError` naming the file; a missing or unreadable
photo is shown as such in the page (and listed in ``HtmlReport.problems``), never a traceback.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np

from insulator_rs.exceptions import ReportError
from insulator_rs.report.folder import write_atomic
from insulator_rs.report.run_status import RunOutcome

HTML_NAME = "report.html"
SUMMARY_NAME = "summary.json"
GEOJSON_NAME = "inspection.geojson"
THUMB_WIDTH = 320  # px: thumbnails are scaled down to this width (never up)
THUMB_QUALITY = 80  # JPEG quality of the embedded thumbnails
MAP_SIZE = 460  # px: each map panel is a square of this side
MAP_MARGIN = 28  # px inside a panel kept free of drawing (labels, scale bar)
MAX_GSD_MM = 2.0  # mm/px: what defect inspection needs (perception.photo_quality.MAX_GSD_MM)
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

    def xy(self, a: float, b: float) -> tuple[float, float]:
        return (MAP_SIZE / 2 + (a - self.center[0]) * self.scale, MAP_SIZE / 2 - (b - self.center[1]) * self.scale)


def _fmt(v: float) -> str:
    return f"{v:.1f}"


def _map_svg(title: str, axes: tuple[str, str], pts_by_kind: dict[str, np.ndarray], path: np.ndarray,
             insulators: list[dict[str, Any]], photos: list[dict[str, Any]], headings: list[np.ndarray | None],
             *, north_arrow: bool) -> str:
    everything = [p for p in (path, *pts_by_kind.values()) if len(p)]
    panel = _Panel(np.vstack(everything)[:, :2])
    out = [f'<svg class="map" xmlns="http://www.w3.org/2000/svg" width="{MAP_SIZE}" height="{MAP_SIZE}" '
           f'viewBox="0 0 {MAP_SIZE} {MAP_SIZE}" role="img" aria-label="{html.escape(title)}">',
           f'<rect x="0" y="0" width="{MAP_SIZE}" height="{MAP_SIZE}" fill="#f7f7f4" stroke="#bbb"/>',
           f'<text x="8" y="16" class="maptitle">{html.escape(title)}</text>']
    if len(path) >= 2:
        d = " ".join(f"{_fmt(x)},{_fmt(y)}" for x, y in (panel.xy(a, b) for a, b in path[:, :2]))
        out.append(f'<polyline class="path" points="{d}" fill="none" stroke="#7a8ca3" stroke-width="1.2"/>')
    base = pts_by_kind.get("tower_base", np.zeros((0, 2)))
    for a, b in base[:, :2]:
        x, y = panel.xy(a, b)
        out.append(f'<rect class="tower" x="{_fmt(x - 5)}" y="{_fmt(y - 5)}" width="10" height="10" fill="#333">'
                   f'<title>tower base</title></rect>')
    for ph, (a, b), head in zip(photos, pts_by_kind.get("photo", np.zeros((0, 2))), headings):
        x, y = panel.xy(a, b)
        if head is not None:
            x2, y2 = panel.xy(a + head[0], b + head[1])
            out.append(f'<line x1="{_fmt(x)}" y1="{_fmt(y)}" x2="{_fmt(x2)}" y2="{_fmt(y2)}" stroke="#1f6fd1" '
                       f'stroke-width="1.2"/>')
        out.append(f'<a href="#{_anchor(ph)}"><circle class="photo-marker" cx="{_fmt(x)}" cy="{_fmt(y)}" r="3.5" '
                   f'fill="#1f6fd1"><title>{html.escape(ph["file"])}</title></circle></a>')
    labels: list[tuple[float, float, list[str]]] = []  # markers closer than 16 px share one label
    for ins, (a, b) in zip(insulators, pts_by_kind.get("insulator", np.zeros((0, 2)))):
        x, y = panel.xy(a, b)
        color = {"fit": "#1a9850", "unfit": "#f28e2b", "none": "#d62728"}[ins["_verdict"]]
        out.append(f'<a href="#insulator-{html.escape(str(ins["id"]))}"><circle class="insulator-marker" '
                   f'cx="{_fmt(x)}" cy="{_fmt(y)}" r="6" fill="{color}" stroke="#222" stroke-width="0.8">'
                   f'<title>insulator {html.escape(str(ins["id"]))}</title></circle></a>')
        near = next((lab for lab in labels if math.hypot(lab[0] - x, lab[1] - y) < 16.0), None)
        if near is None:
            labels.append((x, y, [str(ins["id"])]))
        else:
            near[2].append(str(ins["id"]))
    for x, y, ids in labels:
        out.append(f'<text x="{_fmt(x + 8)}" y="{_fmt(y - 6)}" class="label">{html.escape(", ".join(ids))}</text>')
    # scale bar and axes
    bar = _nice_length(panel.span)
    px = bar * panel.scale
    y0 = MAP_SIZE - 12
    out.append(f'<line x1="12" y1="{y0}" x2="{_fmt(12 + px)}" y2="{y0}" stroke="#000" stroke-width="2"/>'
               f'<text x="12" y="{y0 - 5}" class="small">{bar:g} m</text>'
               f'<text x="{MAP_SIZE - 8}" y="{MAP_SIZE - 8}" class="small" text-anchor="end">'
               f'{html.escape(axes[0])} → / {html.escape(axes[1])} ↑</text>')
    if north_arrow:
        out.append(f'<g transform="translate({MAP_SIZE - 22},34)"><polygon points="0,-14 6,4 0,0 -6,4" fill="#000"/>'
                   f'<text x="0" y="16" class="small" text-anchor="middle">N</text></g>')
    out.append("</svg>")
    return "".join(out)


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
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if len(data) else None
    if image is None or image.size == 0:
        return None, None, "not a decodable image"
    h, w = image.shape[:2]
    if w > THUMB_WIDTH:
        image = cv2.resize(image, (THUMB_WIDTH, max(1, round(h * THUMB_WIDTH / w))), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, THUMB_QUALITY])
    if not ok:
        return None, (w, h), "could not be scaled down"
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii"), (w, h), None


def _quality_reasons(q: Mapping[str, Any] | None) -> list[str]:
    """Why a photo is not fit for inspection, in words (empty when it is)."""
    if not isinstance(q, Mapping):
        return ["no quality figures"]
    if q.get("fit_for_inspection"):
        return []
    out = []
    gsd = _number(q.get("gsd_mm_px"))
    if gsd is None or gsd > MAX_GSD_MM:
        out.append(f"GSD {'∞' if gsd is None else f'{gsd:.1f}'} mm/px > {MAX_GSD_MM:g}")
    if q.get("whole_in_frame") is False:
        out.append("string cut by the border")
    if q.get("sharp") is False:
        blur = _number(q.get("motion_blur_px"))
        out.append(f"motion blur {'?' if blur is None else f'{blur:.1f}'} px")
    return out or ["not fit for inspection"]


def _check_reasons(check: Any) -> list[str]:
    """Why the photo's own check (perception/photo_check.py) found it unfit, in words (empty when
    fit or not checked)."""
    if not isinstance(check, Mapping) or check.get("fit"):
        return []
    out = [str(r) for r in check.get("reasons") or []] or ["unfit"]
    if check.get("error"):
        out.append(str(check["error"]))
    return out


def _photo_fit(p: Mapping[str, Any]) -> bool:
    """Fit for inspection by its figures and, where it was checked on itself, by its check."""
    return bool((p.get("quality") or {}).get("fit_for_inspection")) and not _check_reasons(p.get("check"))


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


# -- the page --------------------------------------------------------------------------------

_CSS = """
body{font:14px/1.4 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;color:#222;background:#fff}
header{background:#23395d;color:#fff;padding:14px 22px}
header h1{margin:0;font-size:22px}
header .sub{opacity:.85;font-size:13px}
main{padding:10px 22px 40px}
h2{border-bottom:2px solid #23395d;padding-bottom:2px;margin-top:26px}
.status{display:inline-block;padding:2px 10px;border-radius:10px;font-weight:600;background:#ccc;color:#000}
.status.finished{background:#1a9850;color:#fff}.status.aborted,.status.failed{background:#d62728;color:#fff}
.status.running,.status.interrupted{background:#f28e2b;color:#000}
.cards{display:flex;flex-wrap:wrap;gap:10px;margin:12px 0}
.card{border:1px solid #ccd;border-radius:6px;padding:8px 14px;min-width:120px;background:#f6f8fb}
.card .v{font-size:22px;font-weight:600}.card .k{font-size:12px;color:#556}
table{border-collapse:collapse;margin:6px 0}td,th{border:1px solid #ddd;padding:3px 8px;text-align:left;vertical-align:top}
th{background:#f0f2f5}
.maps{display:flex;flex-wrap:wrap;gap:16px}
.map .maptitle{font-weight:600;font-size:13px}.map .label{font-size:12px;font-weight:600}.map .small{font-size:11px}
.legend span{display:inline-block;margin-right:14px}.dot{display:inline-block;width:11px;height:11px;border-radius:6px;margin-right:4px;vertical-align:-1px}
.insulator{border:1px solid #ccd;border-radius:6px;padding:4px 16px 12px;margin:14px 0}
.photos{display:flex;flex-wrap:wrap;gap:14px}
figure{margin:0;border:1px solid #ddd;padding:6px;border-radius:4px;max-width:330px}
figure img{display:block;max-width:320px;height:auto}
figcaption{font-size:12px}
.fit{color:#1a9850;font-weight:600}.unfit{color:#c0392b;font-weight:600}
.missing{width:320px;height:120px;background:#fdecea;color:#a00;display:flex;align-items:center;justify-content:center}
.problems{background:#fdecea;border:1px solid #e6a1a1;padding:6px 12px;border-radius:4px}
"""


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

    # each insulator's verdict: a fit photo, photos but none fit, no photo
    by_ins: dict[Any, list[dict[str, Any]]] = {}
    for ph in photos:
        by_ins.setdefault(ph.get("insulator_id"), []).append(ph)
    for ins in insulators:
        mine = by_ins.get(ins["id"], [])
        ins["_photos"] = mine
        ins["_verdict"] = ("fit" if any(_photo_fit(p) for p in mine) else "unfit" if mine else "none")

    # the map from the GeoJSON: points in the order the writer puts them, matched by kind
    pts = {k: _local(np.vstack([f["coords"] for f in features if f["kind"] == k and f["type"] == "Point"]), base)
           for k in ("tower_base", "insulator", "photo") if any(f["kind"] == k for f in features)}
    line = [f for f in features if f["kind"] == "flight_path" and f["type"] == "LineString"]
    path = _local(line[0]["coords"], base) if line else np.zeros((0, 3))
    geo_ins = [f["properties"].get("id") for f in features if f["kind"] == "insulator"]
    geo_photos = [f["properties"] for f in features if f["kind"] == "photo"]
    map_ins = [next((i for i in insulators if i["id"] == gid), {"id": gid, "_verdict": "none"}) for gid in geo_ins]
    map_photos = [{"file": str(p.get("file", "photo"))} for p in geo_photos]
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
    maps = (_map_svg("top view", ("east", "north"), top, path[:, :2], map_ins, map_photos, headings, north_arrow=True)
            + _map_svg("side view (across the line)", ("across", "up"), side_pts, side(path) if len(path) else path,
                       map_ins, map_photos, side_heads, north_arrow=False))

    # summary figures
    status = str(s.get("status", "unknown"))
    skipped = s.get("inspections_skipped") or []
    fit_photos = sum(1 for p in photos if _photo_fit(p))
    checks_v = s.get("photo_checks")
    checks: dict[str, Any] = checks_v if isinstance(checks_v, dict) else {}
    checked_out = {w.get("insulator_id"): w for w in checks.get("insulators_without_fit_photo") or []
                   if isinstance(w, dict)}
    no_fit = [i for i in insulators if i["_verdict"] != "fit"]
    e = html.escape
    title = f"Insulator inspection — {s.get('scene') or Path(str(s.get('mission') or folder.name)).stem}"
    parts = [f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{e(title)}</title>'
             f'<meta name="viewport" content="width=device-width,initial-scale=1"><style>{_CSS}</style></head><body>',
             f'<header><h1>{e(title)}</h1><div class="sub">report folder {e(folder.name)} · started '
             f'{e(str(s.get("started_utc", "–")))} · mission {e(str(s.get("mission", "–")))}</div></header><main>',
             '<section id="summary"><h2>Summary</h2>',
             f'<p>Status: <span class="status {e(_status_class(status))}" id="status">{e(status)}</span></p>',
             '<div class="cards">']
    cards = [("found", len(insulators), "insulators found"),
             ("inspected", sum(1 for i in insulators if i.get("inspected")), "insulators inspected"),
             ("skipped", len(skipped), "inspections skipped"),
             ("photos", len(photos), "photos"),
             ("fit", fit_photos, "photos fit for inspection"),
             ("retakes", checks.get("retakes", 0), "photos retaken (checked unfit)"),
             ("flight-time", _duration(_number(s.get("flight_time_s"))), "flight time"),
             ("distance", _num(s.get("distance_m"), ".0f", " m"), "flown")]
    for key, value, label in cards:
        parts.append(f'<div class="card" id="card-{key}"><div class="v">{e(str(value))}</div>'
                     f'<div class="k">{e(label)}</div></div>')
    parts.append("</div><table>")
    origin = s.get("origin") or {}
    facts = [("run", s.get("run")), ("recording", s.get("recording")),
             ("detector", s.get("detector")), ("localization", s.get("method")), ("vehicle", s.get("vehicle")),
             ("sensors", s.get("sensors")),
             ("tower base (WGS-84)", f"{_num(origin.get('lat'), '.7f')}°, {_num(origin.get('lon'), '.7f')}°, "
                                     f"{_num(origin.get('alt'), '.1f', ' m')}" if origin else None)]
    fs = s.get("failsafe")
    if isinstance(fs, dict):
        facts.append(("failsafe", f"{fs.get('reason')}; action: {fs.get('action')}"))
    facts.append(("battery", _battery_fact(s.get("battery"), s.get("abort"))))
    for k, v in facts:
        if v is not None:
            parts.append(f"<tr><th>{e(k)}</th><td>{e(str(v))}</td></tr>")
    parts.append("</table>")
    if skipped:
        parts.append('<h3>Skipped inspections</h3><table id="skipped"><tr><th>insulator</th><th>reason</th></tr>')
        for it in skipped:
            it = it if isinstance(it, dict) else {"reason": str(it)}
            parts.append(f"<tr><td>{e(str(it.get('insulator_id', '–')))}</td><td>{e(str(it.get('reason', '')))}</td></tr>")
        parts.append("</table>")
    if no_fit:
        parts.append('<h3>Insulators without a photo fit for inspection</h3><table id="no-fit">'
                     '<tr><th>insulator</th><th>why</th></tr>')
        for ins in no_fit:
            if not ins["_photos"]:
                why = "not inspected" if not ins.get("inspected") else "no photo"
                why += "".join(f"; skipped: {it.get('reason')}" for it in skipped
                               if isinstance(it, dict) and it.get("insulator_id") == ins["id"])
            else:
                best = min(ins["_photos"], key=lambda p: _number((p.get("quality") or {}).get("gsd_mm_px")) or math.inf)
                n = len(ins["_photos"])
                why = (f"{n} photo{'s' if n > 1 else ''}, none fit; the finest: "
                       + ", ".join(_quality_reasons(best.get("quality"))))
            out = checked_out.get(ins["id"])
            if out is not None and out.get("photos"):
                why += "; checked on the photos: " + ", ".join(
                    f"{r} ({k}x)" for r, k in (out.get("reasons") or {}).items())
                why += "".join(f"; detector error: {err}" for err in out.get("errors") or [])
            parts.append(f'<tr><td><a href="#insulator-{e(str(ins["id"]))}">{e(str(ins["id"]))}</a></td>'
                         f"<td>{e(why)}</td></tr>")
        parts.append("</table>")
    parts.append("</section>")

    parts.append('<section id="map"><h2>Map</h2><div class="maps">' + maps + "</div>"
                 '<p class="legend"><span><i class="dot" style="background:#1a9850"></i>insulator with a fit photo</span>'
                 '<span><i class="dot" style="background:#f28e2b"></i>photos, none fit</span>'
                 '<span><i class="dot" style="background:#d62728"></i>no photo</span>'
                 '<span><i class="dot" style="background:#1f6fd1"></i>photo position (line: heading)</span>'
                 '<span><i class="dot" style="background:#333;border-radius:0"></i>tower base</span>'
                 '<span>grey line: flown path</span></p></section>')

    parts.append('<section id="insulators"><h2>Insulators</h2>')
    for ins in insulators:
        iid = e(str(ins["id"]))
        g = ins["wgs84"]
        c = ins.get("center") or [None] * 3
        verdict = {"fit": '<span class="fit">fit photo</span>', "unfit": '<span class="unfit">no fit photo</span>',
                   "none": '<span class="unfit">no photo</span>'}[ins["_verdict"]]
        side_v = ins.get("side")
        side_text = ("+ side of the line" if side_v == 1 else "− side of the line" if side_v == -1
                     else "–" if side_v is None else str(side_v))
        parts.append(f'<section class="insulator" id="insulator-{iid}" data-insulator-id="{iid}">'
                     f'<h3>Insulator {iid} · {verdict}</h3><table>'
                     f'<tr><th>WGS-84</th><td class="wgs84">{_latlon(g["lat"], g["lon"])}, {g["alt"]:.2f} m</td></tr>'
                     f'<tr><th>W (ENU at the tower base)</th><td>{_num(c[0])}, {_num(c[1])}, {_num(c[2])} m</td></tr>'
                     f'<tr><th>side</th><td class="side">{e(side_text)}</td></tr>'
                     f'<tr><th>observations</th><td>{e(str(ins.get("observations", "–")))}</td></tr>'
                     f'<tr><th>inspected</th><td>{_yes(ins.get("inspected"))}</td></tr></table>')
        parts.append(_photos_html(folder, ins["_photos"], report))
        parts.append("</section>")
    others = [p for p in photos if p.get("insulator_id") not in {i["id"] for i in insulators}]
    if others:
        parts.append('<section class="insulator" id="other-photos"><h3>Photos of no listed insulator</h3>')
        parts.append(_photos_html(folder, others, report))
        parts.append("</section>")
    parts.append("</section>")
    if report.problems:
        parts.append('<section id="problems"><h2>Problems</h2><ul class="problems">'
                     + "".join(f"<li>{e(p)}</li>" for p in report.problems) + "</ul></section>")
    parts.append('<footer><p class="small">Written by insulator_rs from summary.json and inspection.geojson of this '
                 'folder; photos in images/ (thumbnails embedded). Altitudes in the vertical datum of the mission '
                 "tower's altitude.</p></footer></main></body></html>")
    return "".join(parts), report


def _photos_html(folder: Path, photos: Sequence[Mapping[str, Any]], report: HtmlReport) -> str:
    if not photos:
        return "<p>No photo.</p>"
    e = html.escape
    out = ['<div class="photos">']
    for ph in photos:
        rel = str(ph["file"])
        target = folder / rel
        thumb: str | None
        size: tuple[int, int] | None
        problem: str | None
        if Path(rel).is_absolute() or ".." in Path(rel).parts:
            thumb, size, problem = None, None, "outside the report folder"
        else:
            thumb, size, problem = _thumbnail(target)
        href = quote(rel)
        q = ph.get("quality") if isinstance(ph.get("quality"), dict) else None
        reasons = _quality_reasons(q) + [f"checked: {r}" for r in _check_reasons(ph.get("check"))]
        verdict = '<span class="fit">fit for inspection</span>' if not reasons else \
            f'<span class="unfit">not fit: {e(", ".join(reasons))}</span>'
        if thumb is not None:
            img = (f'<a href="{e(href)}" class="full"><img class="thumb" src="{thumb}" alt="{e(rel)}" '
                   f'title="{e(rel)}"></a>')
        else:
            report.problems.append(f"{rel}: {problem}")
            img = f'<div class="missing">{e(rel)}: {e(problem or "")}</div>'
        geo_v = ph.get("wgs84")
        geo: Mapping[str, Any] = geo_v if isinstance(geo_v, dict) else {}
        rows = [("file", f'<a href="{e(href)}">{e(rel)}</a>' + (f" ({size[0]}×{size[1]} px)" if size else "")),
                ("time (UTC)", e(str(ph.get("time_utc", "–")))),
                ("from", f"{_num(geo.get('lat'), '.7f')}°, {_num(geo.get('lon'), '.7f')}°, {_num(geo.get('alt'), '.1f')} m"),
                ("heading / gimbal", f"{_num(ph.get('heading_deg'), '.1f', '°')} / {_num(ph.get('gimbal_pitch_deg'), '.1f', '°')}")]
        if q is not None:
            rows += [("GSD", _num(q.get("gsd_mm_px"), ".2f", " mm/px")),
                     ("span / area of frame", f"{_pct(q.get('span_share'))} / {_pct(q.get('frame_share'))}"),
                     ("whole in frame", _yes(q.get("whole_in_frame"))),
                     ("motion blur", _num(q.get("motion_blur_px"), ".2f", " px"))]
        c = ph.get("check") if isinstance(ph.get("check"), dict) else None
        if c is not None:
            off = [f"{100 * float(o):+.1f} %" if _number(o) is not None else "open" for o in c.get("offset") or []]
            rows += [("checked on the photo", e(f"attempt {ph.get('attempt', 1)}: "
                                                + ("fit" if c.get("fit") else "unfit: " + ", ".join(_check_reasons(c))))),
                     ("detected span / offset", e(f"{_pct(c.get('span_share'))} (needs {_pct(c.get('min_span'))}) / "
                                                  + (", ".join(off) or "–"))),
                     ("sharpness (Laplacian var.)", _num(c.get("sharpness"), ".0f"))]
        table = "".join(f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in rows)
        out.append(f'<figure class="photo" id="{_anchor(ph)}" data-file="{e(rel)}">{img}'
                   f"<figcaption>{verdict}<table>{table}</table></figcaption></figure>")
    out.append("</div>")
    return "".join(out)


def write_report_html(folder: Path) -> HtmlReport:
    """Write ``report.html`` into the report ``folder`` atomically (a kill leaves the old page or the
    new one); raises ReportError for a folder that is not a readable report (see the module)."""
    text, report = render_report_html(Path(folder))
    write_atomic(report.path, text)
    return report
