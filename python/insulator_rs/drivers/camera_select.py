"""``--camera SOURCE``: which camera source opens it.

* ``gst:PIPELINE``: the pipeline through GStreamer itself (:mod:`.gstreamer_camera`, PyGObject);
* a string containing ``!`` (a pipeline, as ``gst-launch-1.0`` takes it): the same, where
  PyGObject's GStreamer can be imported -- its frames carry their exposure time; otherwise
  OpenCV's GStreamer backend where OpenCV has one (frames stamped on arrival); otherwise a
  SensorError that says what to install;
* anything else (a V4L2 index, a URL, a video file): OpenCV (:mod:`.camera`).

The GStreamer module is imported only when a pipeline is asked for: the onboard package
imports without PyGObject (the ``gstreamer`` extra).
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable

import cv2
import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.drivers.camera import OpenCvCamera
from insulator_rs.drivers.camera_source import CameraSource
from insulator_rs.exceptions import SensorError

#: The prefix that sends ``--camera`` to the PyGObject source whatever else is installed.
GST_PREFIX = "gst:"
#: What to install for GStreamer pipelines, as the errors say it.
INSTALL_HINT = ("pip install 'insulator_rs[gstreamer]' (PyGObject; Debian/Ubuntu: gir1.2-gstreamer-1.0, "
                "gir1.2-gst-plugins-base-1.0), or on JetPack apt install python3-gi gir1.2-gstreamer-1.0 "
                "and a venv made with --system-site-packages")


@functools.lru_cache(maxsize=1)
def opencv_has_gstreamer() -> bool:
    """Whether this OpenCV was built with its GStreamer backend (pip's wheels are not)."""
    match = re.search(r"^\s*GStreamer:\s*(\S+)", cv2.getBuildInformation(), re.MULTILINE)
    return match is not None and match.group(1).upper() != "NO"


def gstreamer_import_error() -> str | None:
    """None where the PyGObject source can be imported, else why not."""
    try:
        import insulator_rs.drivers.gstreamer_camera  # noqa: F401
    except (ImportError, ValueError) as exc:  # no gi, or gi without the Gst typelib (ValueError)
        return f"{type(exc).__name__}: {exc}"
    return None


def camera_backend(source: int | str) -> str:
    """``"gstreamer"`` (PyGObject) or ``"opencv"`` for ``source`` (see the module docstring)."""
    if isinstance(source, str) and source.startswith(GST_PREFIX):
        return "gstreamer"
    if isinstance(source, str) and "!" in source:
        if gstreamer_import_error() is None or not opencv_has_gstreamer():
            return "gstreamer"
    return "opencv"


def open_camera(source: int | str, *, camera: CameraModel, T_b_c: np.ndarray, now: Callable[[], float],
                latency_s: float = 0.0, realtime: bool = True) -> CameraSource:
    """Opens and starts the camera ``--camera SOURCE`` names; SensorError names ``--camera``
    when it cannot (a bad pipeline, no PyGObject for one, a missing file or device)."""
    if camera_backend(source) == "opencv":
        return OpenCvCamera(source, camera=camera, T_b_c=T_b_c, now=now, realtime=realtime,
                            latency_s=latency_s).start()
    assert isinstance(source, str)
    problem = gstreamer_import_error()
    if problem is not None:
        raise SensorError(f"--camera: {source!r} is a GStreamer pipeline, which needs GStreamer's Python "
                          f"bindings (this OpenCV has no GStreamer), and they do not import ({problem}): "
                          f"{INSTALL_HINT}")
    from insulator_rs.drivers.gstreamer_camera import GstCamera

    pipeline = source[len(GST_PREFIX):] if source.startswith(GST_PREFIX) else source
    return GstCamera(pipeline, camera=camera, T_b_c=T_b_c, now=now, latency_s=latency_s).start()
