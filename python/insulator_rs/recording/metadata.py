"""What a recording says about its flight: the mission file and the scene, as an MCAP
metadata record named ``insulator_rs`` (other tools ignore it; Foxglove lists it).

A replay takes the mission from there unless ``--mission`` is given; a recording without it
(any bag from another recorder) needs ``--mission``. A mission that says ``takeoff = "home"`` took
off from the vehicle's home, read from the autopilot before planning (:mod:`insulator_rs.flight.home`):
the record keeps that point (``takeoff``), and the replay's mission takes off from it, from the
recorded mission or from ``--mission`` alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from insulator_rs._toml import tomllib
from insulator_rs.exceptions import ConfigError
from insulator_rs.geodesy import GeoPoint
from insulator_rs.mission.config import Mission, parse_mission

RECORD_NAME = "insulator_rs"


@dataclass(frozen=True)
class FlightMetadata:
    """``mission_text`` and its ``mission_suffix`` (.toml/.yaml), ``scene`` (a simulated
    flight's scene name, for scoring against its ground truth; "" for a real flight),
    ``camera_latency_s`` (the latency, s, the flight's camera subtracted from its frames' arrival
    stamps: the rig's ``[camera] latency_s`` for a live camera, 0 for the simulator's, which
    stamps the exposure; "" in recordings from before it was kept: not known), ``takeoff`` (the
    take-off point of a ``takeoff = "home"`` mission, the vehicle's home as the flight read it:
    :func:`takeoff_record`; "" for a mission that names its own, and in recordings from before it
    was kept)."""

    mission_text: str = ""
    mission_suffix: str = ".toml"
    mission_source: str = ""
    scene: str = ""
    camera_latency_s: str = ""
    takeoff: str = ""

    def as_record(self) -> dict[str, str]:
        return {"mission_text": self.mission_text, "mission_suffix": self.mission_suffix,
                "mission_source": self.mission_source, "scene": self.scene,
                "camera_latency_s": self.camera_latency_s, "takeoff": self.takeoff}

    def flown_takeoff(self) -> GeoPoint | None:
        """The home a ``takeoff = "home"`` flight took off from (WGS-84); None when not recorded.
        ConfigError naming ``takeoff`` when the record holds something else than three numbers."""
        if not self.takeoff:
            return None
        try:
            lat, lon, alt = (float(x) for x in self.takeoff.split(","))
        except ValueError as exc:
            raise ConfigError(f"the recording's takeoff: expected 'lat,lon,alt', got {self.takeoff!r}") from exc
        return GeoPoint(lat, lon, alt)

    def at_flown_takeoff(self, mission: Mission) -> Mission:
        """``mission`` taking off where the recorded flight did, when it says ``takeoff = "home"``
        and the recording kept that home (as :func:`insulator_rs.flight.home.at_vehicle_home` put it
        there for the flight); as it is otherwise (a recording from before the home was kept plans
        from the mission's default take-off point)."""
        point = self.flown_takeoff()
        if not mission.takeoff_home or mission.takeoff is not None or point is None:
            return mission
        return mission.with_takeoff(point)

    def recorded_camera_latency(self) -> float | None:
        """The latency the recorded frames' stamps already carry (s); None when not recorded."""
        if not self.camera_latency_s:
            return None
        try:
            value = float(self.camera_latency_s)
        except ValueError:
            return None
        return value if np.isfinite(value) else None

    def mission(self, recording: Path) -> Mission | None:
        if not self.mission_text:
            return None
        source = f"{recording} (mission recorded from {self.mission_source or 'the flight'})"
        try:
            data: Any = (tomllib.loads(self.mission_text) if self.mission_suffix == ".toml"
                         else yaml.safe_load(self.mission_text))
        except (tomllib.TOMLDecodeError, yaml.YAMLError) as exc:
            raise ConfigError(f"{source}: cannot parse: {exc}") from exc
        return self.at_flown_takeoff(parse_mission(data, source, base=self.mission_folder(recording)))

    def mission_folder(self, recording: Path) -> Path:
        """Where the recorded mission's relative paths (its rig file, and the rig's calibration
        files) start: the folder the mission was flown from when it is still there (a replay on
        the vehicle, or of a copied flight folder), else the recording's own folder (the rig
        files copied beside the recording)."""
        if self.mission_source and Path(self.mission_source).is_absolute():  # older recordings: relative
            flown_from = Path(self.mission_source).parent
            if flown_from.is_dir():
                return flown_from
        return Path(recording).resolve().parent


def mcap_file(path: Path) -> Path | None:
    """The MCAP file of a recording (the file itself, or the single .mcap of a rosbag2 folder)."""
    path = Path(path)
    if path.is_file() and path.suffix == ".mcap":
        return path
    if path.is_dir():
        files = sorted(path.glob("*.mcap"))
        return files[0] if files else None
    return None


def read_metadata(path: Path) -> FlightMetadata:
    """The ``insulator_rs`` record of a recording; empty when there is none (not an MCAP file,
    another recorder's file). A file that is not readable MCAP is left for the reader to refuse."""
    from mcap.reader import make_reader

    from mcap.stream_reader import StreamReader

    f = mcap_file(path)
    if f is None:
        return FlightMetadata()
    records: list[Any] = []
    try:
        with f.open("rb") as stream:
            records = [r for r in make_reader(stream).iter_metadata() if r.name == RECORD_NAME]
    except Exception:  # no summary (a file cut short): look for the record from the start
        records = []
        try:
            with f.open("rb") as stream:
                for rec in StreamReader(stream).records:
                    r: Any = rec
                    if type(r).__name__ == "Metadata" and r.name == RECORD_NAME:
                        records.append(r)
                        break
        except Exception:  # the cut came first: no metadata to be had
            pass
    if not records:
        return FlightMetadata()
    m = dict(records[0].metadata)
    return FlightMetadata(m.get("mission_text", ""), m.get("mission_suffix", ".toml"), m.get("mission_source", ""),
                          m.get("scene", ""), m.get("camera_latency_s", ""), m.get("takeoff", ""))


def takeoff_record(mission: Mission) -> str:
    """What the record keeps of ``mission``'s take-off point: "lat,lon,alt" (repr: every digit, so
    the replay plans from the very point) when the point came from the vehicle's home
    (``takeoff = "home"``, resolved), else "" (the mission file names its own)."""
    if not mission.takeoff_home or mission.takeoff is None:
        return ""
    t = mission.takeoff
    return f"{t.lat!r},{t.lon!r},{t.alt!r}"
