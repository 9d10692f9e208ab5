"""A whole-process stall made on purpose, as a long C call or a long GIL hold makes: one function
holds the interpreter for a known time (``sys.setswitchinterval`` raised so that no other Python
thread runs meanwhile)."""

from __future__ import annotations

import sys
import time


def hold_the_interpreter(seconds: float) -> None:
    old = sys.getswitchinterval()
    sys.setswitchinterval(10.0)  # no other thread gets the GIL until this returns
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            pass
    finally:
        sys.setswitchinterval(old)
