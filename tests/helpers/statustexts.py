"""The STATUSTEXTs in a MAVLink GCS observer's datagrams (what the pilot's ground station
would show), parsed back with pymavlink."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as M


class Statustexts:
    """The GCS observer's datagrams, parsed back with pymavlink."""

    def __init__(self) -> None:
        self.mav = M.MAVLink(None)
        self.texts: list[tuple[int, str]] = []

    def __call__(self, buf: bytes) -> None:
        for msg in self.mav.parse_buffer(buf) or []:
            if msg.get_type() == "STATUSTEXT":
                self.texts.append((msg.severity, msg.text))
