"""Reading a configuration file (mission, scene, calibration) as text, with errors that name it.

A careless or hostile path must give a :class:`~insulator_rs.exceptions.ConfigError` naming the
file, never a traceback: a directory is reported as a directory (not "no such file"), a binary
or Latin-1 file as not UTF-8 (with the offset of the first bad byte), a huge file as too large
before it is read into memory.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from insulator_rs.exceptions import ConfigError

#: Largest configuration file read, bytes. Mission, scene and calibration files are a few
#: kilobytes; a bigger one is the wrong file, and YAML/TOML parsers hold it all in memory.
MAX_CONFIG_BYTES = 1 << 20


def read_config_text(path: Path, prefix: str, *,
                     error: Callable[[str], Exception] = ConfigError) -> str:
    """The UTF-8 text of ``path``; problems raise ``error(f"{prefix}: <reason>")``."""
    try:
        if path.is_dir():
            raise error(f"{prefix}: is a directory, not a file")
        if not path.exists():
            raise error(f"{prefix}: no such file")
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise error(f"{prefix}: file too large ({size} bytes; a configuration file is at most "
                        f"{MAX_CONFIG_BYTES} bytes)")
        with path.open("rb") as f:  # bounded read: a device (/dev/zero) has no st_size
            data = f.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise error(f"{prefix}: cannot read ({exc.strerror or exc})") from exc
    if len(data) > MAX_CONFIG_BYTES:
        raise error(f"{prefix}: file too large (a configuration file is at most "
                    f"{MAX_CONFIG_BYTES} bytes)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{prefix}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
                    f"a binary file, or text saved in another encoding (save it as UTF-8)") from None
