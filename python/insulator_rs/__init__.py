"""insulator_rs: onboard insulator detection, localization and inspection planning for UAVs.

The heavy geometry lives in the compiled extension ``insulator_rs._core`` (Rust);
this package re-exports its public API and adds the Python orchestration.
"""

from __future__ import annotations

__all__: list[str] = []
