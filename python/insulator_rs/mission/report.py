"""The inspection report folder, written as the mission goes so an interruption loses nothing.

Layout: ``summary.json`` (rewritten atomically after every event),
``insulators.csv`` (rewritten with the summary), ``trajectory.csv`` (appended
and flushed), ``images/`` (the inspection photos, PNG, written when taken),
``trajectory.png`` (the flown path round the tower with the waypoints, drawn
at the end and whenever the run stops).
"""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from insulator_rs.mission.safety import SafetyVolumes


def _jsonable(value: Any) -> Any:
    """Plain JSON values: arrays to lists, numpy scalars to Python ones, NaN/inf to null."""
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


class ReportWriter:
    """Writes one report folder (created). The files it writes replace those of an earlier
    run; photos of an earlier run (``images/insulator_*.png``) are removed first so the folder
    describes this run only."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.images = self.folder / "images"
        self.images.mkdir(parents=True, exist_ok=True)
        for old in self.images.glob("insulator_*.png"):
            old.unlink()
        self._traj = (self.folder / "trajectory.csv").open("w", newline="")
        self._traj_writer = csv.writer(self._traj)
        self._traj_writer.writerow(["time_s", "x_m", "y_m", "z_m", "yaw_rad", "state"])
        self.trajectory: list[tuple[float, float, float, float]] = []

    def log_pose(self, time: float, position: np.ndarray, yaw: float, state: str) -> None:
        self._traj_writer.writerow([f"{time:.3f}", f"{position[0]:.3f}", f"{position[1]:.3f}",
                                    f"{position[2]:.3f}", f"{yaw:.4f}", state])
        self.trajectory.append((time, float(position[0]), float(position[1]), float(position[2])))

    def flush(self) -> None:
        self._traj.flush()

    def save_image(self, name: str, rgb: np.ndarray) -> Path:
        path = self.images / name
        if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise OSError(f"{path}: could not write the image")
        return path

    def write_summary(self, summary: dict[str, Any]) -> None:
        """summary.json atomically (temp file + rename) and insulators.csv."""
        path = self.folder / "summary.json"
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(_jsonable(summary), indent=2, allow_nan=False))
        os.replace(tmp, path)
        rows = summary.get("insulators", [])
        with (self.folder / "insulators.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["id", "x_m", "y_m", "z_m", "observations", "side", "inspected", "photos",
                        "gt_instance_id", "error_m", "axis_error_deg"])
            for r in rows:
                w.writerow([r["id"], *(f"{c:.3f}" for c in r["center"]), r["observations"], r["side"],
                            r["inspected"], len(r["photos"]), r.get("gt_instance_id"),
                            "" if r.get("error_m") is None else f"{r['error_m']:.3f}",
                            "" if r.get("axis_error_deg") is None else f"{r['axis_error_deg']:.2f}"])

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
        fig.savefig(self.folder / "trajectory.png", dpi=120)
        plt.close(fig)

    def close(self) -> None:
        self._traj.close()
