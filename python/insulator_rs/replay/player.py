"""One pass over a recording, shared by the replay's two adapters.

A recording is read once, in log-time order (:meth:`FlightBag.items`). The replay's
:class:`~insulator_rs.replay.vehicle.ReplayVehicle` moves the clock from one recorded datum to
the next; the scans and frames read on the way wait in this player until the replay's
:class:`~insulator_rs.replay.sensors.ReplaySensors` hands them over, at the time a live source
would have (a frame at its exposure, a scan once the time it covers is over).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator

from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped
from insulator_rs.recording.reader import Item


class RecordingPlayer:
    """The recording's items, one at a time; poses, scans and frames read so far."""

    def __init__(self, items: Iterator[Item]) -> None:
        self._items = items
        self.time: float | None = None  # log time of the latest datum read
        self.pose: PoseStamped | None = None  # the latest recorded pose
        self.scans: deque[LidarScan] = deque()  # read, not yet handed over
        self.frames: deque[CameraFrame] = deque()
        self.counts = {"poses": 0, "scans": 0, "frames": 0}
        self.ended = False

    def next(self) -> Item | None:
        """The next datum (None at the end); a broken recording raises its BagError here."""
        if self.ended:
            return None
        item = next(self._items, None)
        if item is None:
            self.ended = True
            return None
        self.time = item.time if self.time is None else max(self.time, item.time)
        if item.kind == "pose":
            self.pose = item.value
            self.counts["poses"] += 1
        elif item.kind == "scan":
            self.scans.append(item.value)
            self.counts["scans"] += 1
        else:
            self.frames.append(item.value)
            self.counts["frames"] += 1
        return item
