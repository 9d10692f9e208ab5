"""A sensor rig's files as a user writes them: an OpenCV calibration and the body-frame
extrinsics of the camera (``T_B_C``) and the LiDAR (``T_B_L``) a rig file names."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

T_B_C = [[0.0, 0.0, 1.0, 0.05], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, -0.1], [0.0, 0.0, 0.0, 1.0]]
T_B_L = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.12], [0.0, 0.0, 0.0, 1.0]]


def write_opencv_calibration(path: Path) -> None:
    """A real calibration's form: OpenCV FileStorage, principal point off the centre."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1440)
    fs.write("image_height", 1080)
    fs.write("camera_matrix", np.array([[1100.0, 0, 731.2], [0, 1098.5, 528.9], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[-0.21, 0.09, 0.0004, -0.0002, -0.01]]))
    fs.release()


def write_zoom_rig(folder: Path, table: str) -> Path:
    """A rig file with the simulator's zoom calibration as its ``[inspection_camera]``, whose other
    fields are ``table`` (TOML lines)."""
    from insulator_rs.rig import simulator_rig

    zoom_cal = Path(simulator_rig().source).parent / "simulator_inspection_camera.yaml"
    (folder / "zoom.yaml").write_text(zoom_cal.read_text())
    write_opencv_calibration(folder / "cam.yaml")
    rig = folder / "rig.toml"
    rig.write_text(f'[camera]\ncalibration = "cam.yaml"\nT_b_c = {T_B_C}\n\n[lidar]\nT_b_l = {T_B_L}\n\n'
                   f'[inspection_camera]\ncalibration = "zoom.yaml"\n{table}')
    return rig
