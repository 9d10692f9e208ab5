"""MAVLink 2 message signing keys.

A key file holds the 32-byte secret either as 64 hexadecimal characters (one
line, as QGroundControl and MAVProxy print it) or as 32 raw bytes.
"""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

from insulator_rs.exceptions import ConfigError

KEY_LENGTH = 32
# MAVLink signing timestamps count 10 us units since 2015-01-01 00:00 UTC.
SIGNING_EPOCH_UNIX_S = 1420070400


def load_signing_key(path: str | os.PathLike[str]) -> bytes:
    """Read a 32-byte signing key from ``path`` (hex text or raw bytes)."""
    file = Path(path)
    try:
        data = file.read_bytes()
    except OSError as exc:
        raise ConfigError(f"signing key file {file}: cannot read ({exc.strerror})") from exc
    text = data.strip()
    if len(text) == 2 * KEY_LENGTH:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if len(data) == KEY_LENGTH:
        return data
    raise ConfigError(f"signing key file {file}: expected 64 hex characters or 32 raw bytes, "
                      f"got {len(data)} bytes")


def key_from_passphrase(passphrase: str) -> bytes:
    """SHA-256 of a passphrase, as MAVProxy's ``signing setup`` derives keys."""
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def signing_timestamp_now() -> int:
    """Current MAVLink signing timestamp (10 us units since 2015-01-01)."""
    return int(max(0.0, time.time() - SIGNING_EPOCH_UNIX_S) * 100_000)


def configure_signing(mav: object, key: bytes, *, link_id: int, allow_unsigned: frozenset[int]) -> None:
    """Turn on signing of a pymavlink ``MAVLink`` object: sign everything sent, accept
    only correctly signed messages except the message ids in ``allow_unsigned``."""
    if len(key) != KEY_LENGTH:
        raise ValueError(f"key must be {KEY_LENGTH} bytes, got {len(key)}")
    signing = mav.signing  # type: ignore[attr-defined]
    signing.secret_key = bytes(key)
    signing.sign_outgoing = True
    signing.link_id = link_id
    signing.timestamp = signing_timestamp_now()
    signing.allow_unsigned_callback = lambda _mav, msg_id: msg_id in allow_unsigned
