"""TOML reading on every supported Python: the standard library's ``tomllib`` from
3.11, its backport ``tomli`` (same API) on 3.10, the Jetson's JetPack 6 Python."""

from __future__ import annotations

import sys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised by the Python 3.10 CI run
    import tomli as tomllib

__all__ = ["tomllib"]
