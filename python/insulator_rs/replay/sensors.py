"""The replay's :class:`~insulator_rs.ports.sensors.Sensors`: the recorded frames and scans,
handed over when a live source would have delivered them.

* ``detection_frame(now)``: the newest recorded frame exposed at or before ``now`` and not
  handed over yet (older ones the replay's clock passed are counted as skipped: with the
  replay's clock ticking at every recorded datum there are none);
* ``lidar_scan(now)``: every recorded scan whose covered time is over by ``now``, merged into
  one (a live driver's newest scan holds the points since the last; nothing recorded is lost);
* ``photo``: a replay takes no photos (None).

``camera_shift_s``: how much later than the recorded stamps the frames were exposed, by a
calibration made after the flight (the rig's ``[camera] latency_s`` now, less what the flight's
camera already subtracted): each frame is handed over when it arrived in the recording, stamped
``time - camera_shift_s``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.ports.sensors import CameraFrame, LidarScan
from insulator_rs.replay.player import RecordingPlayer


class ReplaySensors:
    """The recording's sensor data, on the replay's clock (see the module docstring)."""

    def __init__(self, player: RecordingPlayer, camera_shift_s: float = 0.0) -> None:
        if not (np.isfinite(camera_shift_s) and abs(camera_shift_s) <= 1.0):
            raise ValueError(f"camera_shift_s: must be a finite number of seconds in [-1, 1], got {camera_shift_s}")
        self.player = player
        self.camera_shift_s = float(camera_shift_s)
        self.counts = {"frames_delivered": 0, "frames_skipped": 0, "scans_delivered": 0}

    def detection_frame(self, now: float) -> CameraFrame | None:
        frames = self.player.frames
        newest = None
        while frames and frames[0].time <= now:
            if newest is not None:
                self.counts["frames_skipped"] += 1
            newest = frames.popleft()
        if newest is None:
            return None
        self.counts["frames_delivered"] += 1
        return replace(newest, time=newest.time - self.camera_shift_s) if self.camera_shift_s else newest

    def lidar_scan(self, now: float) -> LidarScan | None:
        scans = self.player.scans
        ready = []
        # a scan with no point and no window covers nothing: it is dropped (nan compares false)
        while scans and not scans[0].covered_until > now:
            scan = scans.popleft()
            if len(scan) or scan.window_end is not None:  # an empty scan with a window: nothing seen there
                ready.append(scan)
        if not ready:
            return None
        self.counts["scans_delivered"] += len(ready)
        if len(ready) == 1:
            return ready[0]
        intensity = (None if any(s.intensity is None for s in ready)
                     else np.concatenate([np.asarray(s.intensity) for s in ready]))
        return LidarScan(np.concatenate([np.asarray(s.points_l, dtype=np.float64) for s in ready]),
                         np.concatenate([np.asarray(s.times, dtype=np.float64) for s in ready]),
                         ready[-1].T_b_l, intensity, window_end=max(s.covered_until for s in ready))

    def photo(self, now: float, T_b_c: np.ndarray, camera: CameraModel | None = None) -> CameraFrame | None:
        return None

    def health(self) -> dict[str, object]:
        return {"source": "recording", **self.counts, "camera_shift_s": self.camera_shift_s}

    def close(self) -> None:
        pass
