"""The report's map layers: GeoJSON (RFC 7946) and KML of the insulators, the photo
positions, the tower base and the flown path, in WGS-84.

Positions are converted from W (ENU at the tower base, the mission's tower lat/lon/alt)
with pymap3d through :mod:`insulator_rs.geodesy`. GeoJSON positions are
``[longitude, latitude, altitude]`` (RFC 7946 section 3.1.1 order), 1e-9 deg (0.1 mm) and
1e-4 m; no ``crs`` member (RFC 7946 fixes WGS-84). KML uses ``altitudeMode`` absolute.
Altitudes are in the tower altitude's vertical datum (see :mod:`.exif`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.geodesy import GeoPoint, enu_to_geodetic
from insulator_rs.report.folder import write_atomic

DEG_DECIMALS = 9  # 1e-9 deg: 0.1 mm on the ground
ALT_DECIMALS = 4
# m: the flown path keeps a sample when it is this far from the last kept one (a 20 Hz log
# of a hovering vehicle is thousands of equal points; the path's shape needs none of them).
PATH_SPACING = 0.25
# Insulator and photo fields that go on the map (what the flight knows; ground-truth
# comparisons of a simulated flight stay in summary.json).
INSULATOR_FIELDS = ("id", "side", "inspected", "observations", "photos")
PHOTO_FIELDS = ("file", "insulator_id", "time_utc", "heading_deg", "gimbal_pitch_deg")


@dataclass(frozen=True)
class MapPoint:
    """One point of the map: ``kind`` (tower_base, insulator, photo), a label, its position
    in W and in WGS-84 (lat, lon, alt), and its properties."""

    kind: str
    name: str
    enu: tuple[float, float, float]
    geo: tuple[float, float, float]
    properties: dict[str, Any]


@dataclass(frozen=True)
class MapLayers:
    """Everything one report puts on a map."""

    origin: GeoPoint
    points: list[MapPoint]
    path_geo: np.ndarray  # (N, 3) lat, lon, alt of the flown path (N may be < 2: no line)


def map_layers(origin: GeoPoint, *, insulators: Sequence[Mapping[str, Any]],
               photos: Sequence[Mapping[str, Any]], path_enu: np.ndarray) -> MapLayers:
    """The map of a report: insulators (``center`` in W), photos (``position`` in W) and the
    flown path (N, 3) in W (thinned by the caller, e.g. to :data:`PATH_SPACING`), with the
    tower base (W's origin)."""
    rows: list[tuple[str, str, np.ndarray, dict[str, Any]]] = [
        ("tower_base", "tower base", np.zeros(3), {"kind": "tower_base"})]
    for ins in insulators:
        props = {"kind": "insulator", **{k: ins[k] for k in INSULATOR_FIELDS if k in ins}}
        if "axis" in ins:
            props["axis_enu"] = [round(float(c), 4) for c in ins["axis"]]
        rows.append(("insulator", f"insulator {ins['id']}", np.asarray(ins["center"], dtype=np.float64), props))
    for ph in photos:
        props = {"kind": "photo", **{k: ph[k] for k in PHOTO_FIELDS if k in ph}}
        rows.append(("photo", str(ph.get("file", "photo")), np.asarray(ph["position"], dtype=np.float64), props))
    enu = np.array([r[2] for r in rows], dtype=np.float64).reshape(-1, 3)
    geo = enu_to_geodetic(enu, origin)
    points = []
    for (kind, name, e, props), g in zip(rows, geo):
        e_t = (float(e[0]), float(e[1]), float(e[2]))
        props["enu_m"] = [round(c, 4) for c in e_t]
        points.append(MapPoint(kind, name, e_t, (float(g[0]), float(g[1]), float(g[2])), props))
    return MapLayers(origin, points, enu_to_geodetic(np.asarray(path_enu, dtype=np.float64).reshape(-1, 3), origin))


def _position(lat: float, lon: float, alt: float) -> list[float]:
    """An RFC 7946 position (longitude first, as KML's coordinates too), rounded."""
    return [round(lon, DEG_DECIMALS), round(lat, DEG_DECIMALS), round(alt, ALT_DECIMALS)]


def _positions(geo: np.ndarray) -> list[list[float]]:
    """:func:`_position` of (N, 3) lat, lon, alt rows, vectorised (a long flown path)."""
    g = np.asarray(geo, dtype=np.float64).reshape(-1, 3)
    return np.stack([np.round(g[:, 1], DEG_DECIMALS), np.round(g[:, 0], DEG_DECIMALS),
                     np.round(g[:, 2], ALT_DECIMALS)], axis=1).tolist()


def geojson_document(layers: MapLayers) -> dict[str, Any]:
    """A GeoJSON FeatureCollection: one Point per map point, the flown path as a LineString."""
    features: list[dict[str, Any]] = []
    for p in layers.points:
        features.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": _position(*p.geo)},
                         "properties": {"name": p.name, **p.properties}})
    if len(layers.path_geo) >= 2:  # RFC 7946 3.1.4: a LineString has two or more positions
        features.append({"type": "Feature",
                         "geometry": {"type": "LineString",
                                      "coordinates": _positions(layers.path_geo)},
                         "properties": {"name": "flown path", "kind": "flight_path",
                                        "sample_spacing_m": PATH_SPACING}})
    return {"type": "FeatureCollection", "features": features}


def write_geojson(path: Path, layers: MapLayers) -> Path:
    """``path`` (``.geojson``), written atomically."""
    text = json.dumps(geojson_document(layers), allow_nan=False)
    return write_atomic(Path(path), text)


def kml_text(layers: MapLayers, *, title: str = "insulator inspection") -> str:
    """The same map as KML 2.2 (simplekml): folders Insulators, Photos, Tower, and the path."""
    import simplekml

    kml = simplekml.Kml(name=title)
    folders = {"tower_base": kml.newfolder(name="Tower"), "insulator": kml.newfolder(name="Insulators"),
               "photo": kml.newfolder(name="Photos")}
    for p in layers.points:
        pnt = folders[p.kind].newpoint(name=p.name, coords=[tuple(_position(*p.geo))])
        pnt.altitudemode = simplekml.AltitudeMode.absolute
        for key, value in p.properties.items():
            pnt.extendeddata.newdata(name=key, value=json.dumps(value) if not isinstance(value, str) else value)
        if p.kind == "photo" and "file" in p.properties:
            pnt.description = f'<img src="{p.properties["file"]}" width="480"/>'
    if len(layers.path_geo) >= 2:
        line = kml.newlinestring(name="flown path", coords=[tuple(c) for c in _positions(layers.path_geo)])
        line.altitudemode = simplekml.AltitudeMode.absolute
        line.style.linestyle.width = 2
        line.style.linestyle.color = simplekml.Color.yellow
    return str(kml.kml())


def write_kml(path: Path, layers: MapLayers, *, title: str = "insulator inspection") -> Path:
    """``path`` (``.kml``), written atomically."""
    return write_atomic(Path(path), kml_text(layers, title=title))
