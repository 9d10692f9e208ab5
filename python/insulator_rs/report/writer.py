"""The inspection report folder, written as the mission goes so an interruption loses nothing.

Layout (what a line crew gets):

* ``summary.json``: the run (status first ``"running"``, then ``finished``/``aborted: ...``/
  ``interrupted``/``failed``), every insulator in W (ENU at the tower base, m) and in
  WGS-84 (``wgs84``: lat, lon deg, alt m), every photo with its position, heading and UTC
  time; rewritten atomically after every event.
* ``insulators.csv``: one row per insulator, ENU and WGS-84; rewritten with the summary.
* ``images/insulator_II_N.jpg``: the inspection photos, JPEG with EXIF GPS position,
  altitude, heading (true north) and UTC time (:mod:`.exif`), written when taken.
* ``inspection.geojson`` (RFC 7946) and ``inspection.kml``: insulators, photo positions,
  tower base and flown path on a map (:mod:`.geoexport`); rewritten at each photo, status
  change and close.
* ``trajectory.csv`` (appended and flushed) and ``trajectory.png`` (the flown path round
  the tower with the waypoints, drawn at the end and whenever the run stops).

The folder itself is opened by :class:`~.folder.ReportFolder`: a run never writes into
another run's report (see there for ``overwrite``). Altitudes are in the vertical datum
of the mission tower's ``alt`` (see :mod:`.exif`).
"""

from __future__ import annotations

import csv
import io
import math
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.geodesy import GeoPoint, enu_to_geodetic
from insulator_rs.planning.safety import SafetyVolumes
from insulator_rs.report.exif import compass_heading_deg, photo_exif, write_jpeg
from insulator_rs.report.folder import ReportFolder, write_atomic
from insulator_rs.report.jsonfile import jsonable, write_json
from insulator_rs.report.summary import RunSummary
from insulator_rs.report.geoexport import PATH_SPACING, map_layers, write_geojson, write_kml
from insulator_rs.report.html import write_report_html

GEOJSON_NAME = "inspection.geojson"
KML_NAME = "inspection.kml"


def _wgs84(geo: np.ndarray) -> dict[str, float]:
    return {"lat": float(geo[0]), "lon": float(geo[1]), "alt": float(geo[2])}


def utc_text(t: datetime) -> str:
    """ISO 8601 UTC with milliseconds and a Z, as the summary and the map layers give times."""
    return t.astimezone(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _map_key(summary: dict[str, Any]) -> tuple[Any, ...]:
    """When the map layers are rewritten during a run: a new photo (the vehicle hovers then) or a
    new status; a new insulator waits for the next of those (it is in summary.json at once)."""
    return (summary.get("status"), len(summary.get("photos", [])))


class ReportWriter:
    """Writes one run's report folder.

    ``folder``: the report folder (``--out``), opened by :class:`ReportFolder` (created; an
    existing report in it is replaced only with ``overwrite``, at :meth:`close`).
    ``origin``: W's origin in WGS-84, the mission's tower base (lat, lon, alt).
    ``summary.json`` says ``"running"`` from the moment this returns."""

    def __init__(self, folder: Path, *, origin: GeoPoint, overwrite: bool = False) -> None:
        self.layout = ReportFolder(Path(folder), overwrite=overwrite)
        self.folder = self.layout.final
        self.origin = origin
        self.opened_utc = datetime.now(timezone.utc)
        path = self.layout.path
        self.images = path / "images"
        self.trajectory: list[tuple[float, float, float, float]] = []
        # the flown distance, summed as poses come: the periodic summary read it from a copy of
        # the whole trajectory, the flight loop's largest allocation (gc_pauses.py)
        self.distance_m = 0.0
        self._path_kept: list[tuple[float, float, float]] = []  # the flown path thinned to PATH_SPACING
        # The map layers are rewritten at photos, status changes and close, not on every periodic
        # summary: the KML of a 10-minute path costs ~0.1 s the control loop should not wait.
        self._map_key: tuple[Any, ...] | None = None
        self._last_summary: dict[str, Any] = {}
        # summary.json first: from here on the folder says which run it holds and that it is not done
        self._write_summary({"status": "running", "started_utc": utc_text(self.opened_utc),
                             "insulators": [], "photos": []})
        self.images.mkdir(exist_ok=True)
        self._traj = (path / "trajectory.csv").open("w", newline="")
        self._traj_writer = csv.writer(self._traj)
        self._traj_writer.writerow(["time_s", "x_m", "y_m", "z_m", "yaw_rad", "state"])

    def log_pose(self, time: float, position: np.ndarray, yaw: float, state: str) -> None:
        self._traj_writer.writerow([f"{time:.3f}", f"{position[0]:.3f}", f"{position[1]:.3f}",
                                    f"{position[2]:.3f}", f"{yaw:.4f}", state])
        p = (float(position[0]), float(position[1]), float(position[2]))
        if self.trajectory:
            self.distance_m += math.dist(self.trajectory[-1][1:], p)
        self.trajectory.append((time, *p))
        if all(map(math.isfinite, p)) and (not self._path_kept or math.dist(p, self._path_kept[-1]) >= PATH_SPACING):
            self._path_kept.append(p)

    def flush(self) -> None:
        self._traj.flush()

    def save_photo(self, name: str, image_bgr: np.ndarray, *, time_utc: datetime, position_enu: np.ndarray,
                   yaw_enu: float, gimbal_pitch: float | None = None, description: str = "",
                   make: str | None = None, model: str | None = None,
                   focal_length_mm: float | None = None) -> dict[str, Any]:
        """Write ``images/<name>`` (a ``.jpg`` name) with EXIF GPS: position (W -> WGS-84 through
        the origin), heading (from the yaw in W, see :func:`.exif.compass_heading_deg`) and time.
        Returns the photo's report fields: ``file`` (relative to the folder), ``time_utc``,
        ``heading_deg``, ``gimbal_pitch_deg`` (when given) and ``wgs84``."""
        if Path(name).name != name or Path(name).suffix.lower() not in (".jpg", ".jpeg"):
            raise ValueError(f"name: expected a plain .jpg file name, got {name!r}")
        pos = np.asarray(position_enu, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(pos)):
            raise ValueError(f"position_enu: must be finite, got {pos.tolist()}")
        geo = enu_to_geodetic(pos, self.origin)[0]
        heading = compass_heading_deg(yaw_enu)
        text = description
        if gimbal_pitch is not None:
            text = f"{text}; " if text else ""
            text += f"gimbal pitch {math.degrees(gimbal_pitch):.1f} deg"
        exif = photo_exif(geo=GeoPoint(*(float(c) for c in geo)), heading_deg=heading, time_utc=time_utc,
                          description=text, make=make, model=model, focal_length_mm=focal_length_mm)
        write_jpeg(self.images / name, image_bgr, exif=exif)
        record: dict[str, Any] = {"file": f"images/{name}", "time_utc": utc_text(time_utc),
                                  "heading_deg": heading, "wgs84": _wgs84(geo)}
        if gimbal_pitch is not None:
            record["gimbal_pitch_deg"] = math.degrees(gimbal_pitch)
        return record

    def write_summary(self, run: RunSummary) -> None:
        """summary.json atomically (temp file + rename), insulators.csv, and the map layers.

        Added to the run's summary: ``origin`` (W's origin, WGS-84) and each insulator's
        ``wgs84`` position (from its ``center`` in W)."""
        self._write_summary(run.as_dict())

    def _write_summary(self, summary: dict[str, Any]) -> None:
        """The JSON object of a summary (the run's, or the folder's first word: ``running``)."""
        summary.setdefault("started_utc", utc_text(self.opened_utc))
        summary["origin"] = {"lat": self.origin.lat, "lon": self.origin.lon, "alt": self.origin.alt,
                             "frame": "W: ENU (x east, y north, z up), m, at the tower base"}
        rows = [dict(r) for r in summary.get("insulators", [])]
        if rows:
            geo = enu_to_geodetic(np.array([r["center"] for r in rows], dtype=np.float64), self.origin)
            for r, g in zip(rows, geo):
                r["wgs84"] = _wgs84(g)
        summary["insulators"] = rows
        path = self.layout.path
        write_json(path / "summary.json", summary, durable=True)
        table = io.StringIO(newline="")
        w = csv.writer(table)
        w.writerow(["id", "x_m", "y_m", "z_m", "lat_deg", "lon_deg", "alt_m", "observations", "side",
                    "inspected", "photos"])
        for r in rows:
            g = r["wgs84"]
            w.writerow([r["id"], *(f"{c:.3f}" for c in r["center"]), f"{g['lat']:.9f}", f"{g['lon']:.9f}",
                        f"{g['alt']:.3f}", r.get("observations"), r.get("side"), r.get("inspected"),
                        len(r.get("photos", []))])
        write_atomic(path / "insulators.csv", table.getvalue())
        self._last_summary = summary
        if _map_key(summary) != self._map_key:
            self._write_map(summary)

    def _write_map(self, summary: dict[str, Any]) -> None:
        path = list(self._path_kept)
        if path and self.trajectory and self.trajectory[-1][1:] != path[-1]:
            path.append(self.trajectory[-1][1:])  # the path ends where the vehicle is
        layers = map_layers(self.origin, insulators=summary.get("insulators", []),
                            photos=summary.get("photos", []), path_enu=np.array(path).reshape(-1, 3))
        write_geojson(self.layout.path / GEOJSON_NAME, layers)
        title = f"insulator inspection: {summary.get('scene', '')} {summary.get('status', '')}".strip()
        write_kml(self.layout.path / KML_NAME, layers, title=title)
        self._map_key = _map_key(summary)

    def plot(self, volumes: SafetyVolumes, waypoints: np.ndarray, found: np.ndarray,
             truth: np.ndarray, title: str) -> None:
        """trajectory.png: the flown path (top view and side view in W) with the inspection
        waypoints, the localized and the true insulators and the safety boxes."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        traj = np.array(self.trajectory) if self.trajectory else np.zeros((0, 4))
        fig = plt.figure(figsize=(12, 5.5))
        ax3 = fig.add_subplot(1, 2, 1, projection="3d")
        ax2 = fig.add_subplot(1, 2, 2)
        for box in volumes.boxes[:1]:
            corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
            local = corners * box.half_extents
            local[:, 2] = np.clip(local[:, 2] + box.center[2], 0, None) - box.center[2]
            pts = local @ box.axes + box.center
            for i in range(8):
                for j in range(i + 1, 8):
                    if np.sum(corners[i] != corners[j]) == 1:
                        ax3.plot(*pts[[i, j]].T, color="0.6", lw=0.8)
        if len(traj):
            ax3.plot(traj[:, 1], traj[:, 2], traj[:, 3], lw=1.0, label="flown")
            ax2.plot(traj[:, 1], traj[:, 2], lw=1.0, label="flown")
            ax3.scatter(*traj[0, 1:4], color="blue", s=30, label="start")
        for arr, color, marker, label in ((waypoints, "green", "o", "inspection waypoints"),
                                          (found, "red", "x", "localized"),
                                          (truth, "black", "+", "ground truth")):
            if len(arr):
                ax3.scatter(arr[:, 0], arr[:, 1], arr[:, 2], color=color, marker=marker, s=24, label=label)
                ax2.scatter(arr[:, 0], arr[:, 1], color=color, marker=marker, s=24)
        ax3.set_xlabel("x east [m]")
        ax3.set_ylabel("y north [m]")
        ax3.set_zlabel("z up [m]")
        ax3.legend(fontsize=7)
        ax2.set_aspect("equal")
        ax2.set_xlabel("x east [m]")
        ax2.set_ylabel("y north [m]")
        ax2.set_title("top view")
        ax2.grid(alpha=0.3)
        fig.suptitle(title)
        fig.tight_layout()
        fig.savefig(self.layout.path / "trajectory.png", dpi=120)
        plt.close(fig)

    def close(self) -> None:
        """Close the files and put the report in place (with ``overwrite``: replace the old one now)."""
        self._traj.close()
        self._write_map(self._last_summary)  # the whole flown path
        write_report_html(self.layout.path)  # report.html from the folder's own files
        self.layout.commit()
