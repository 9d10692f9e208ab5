"""Run a module as the GPU machine would, here: the packages its image lacks cannot be imported.

    python scripts/gpu/device_like.py insulator_rs.app.gpu_training --out ... --work ...

The device carries only scripts/gpu/requirements.txt's wheels beside its own image
(../.library's device KINDS.md lists it); every other package the project installs is hidden,
so a dry run here fails where the device would. The render processes (spawned) import this file
as their main module and hide the same packages.
"""

from __future__ import annotations

import importlib.abc
import runpy
import sys

# Installed here by the project's extras, absent from the device's image and not carried.
ABSENT_ON_DEVICE = ("pymavlink", "serial", "pymap3d", "ortools", "piexif", "simplekml", "polars",
                    "mcap", "mcap_ros2", "rosbags", "ray", "rerun", "lz4", "mavsdk", "geojson", "vermin",
                    "open3d", "ultralytics_platform", "gi")


class HideAbsent(importlib.abc.MetaPathFinder):
    """Refuses the packages of ABSENT_ON_DEVICE as if they were not installed."""

    def find_spec(self, fullname: str, path: object, target: object = None) -> None:
        if fullname.split(".")[0] in ABSENT_ON_DEVICE:
            raise ModuleNotFoundError(f"No module named {fullname!r} (not on the GPU machine)", name=fullname)
        return None


sys.meta_path.insert(0, HideAbsent())

if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: device_like.py MODULE [ARGS...]")
    module = sys.argv[1]
    sys.argv = [module, *sys.argv[2:]]
    runpy.run_module(module, run_name="__main__", alter_sys=True)
