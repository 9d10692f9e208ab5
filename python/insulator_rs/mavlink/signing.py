"""MAVLink 2 message signing keys.

A key file holds the 32-byte secret either as 64 hexadecimal characters (one
line, as QGroundControl and MAVProxy print it) or as 32 raw bytes.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import struct
import time
import types
from pathlib import Path
from typing import Any

from insulator_rs.exceptions import ConfigError

KEY_LENGTH = 32
# MAVLink signing timestamps count 10 us units since 2015-01-01 00:00 UTC.
SIGNING_EPOCH_UNIX_S = 1420070400
# A new stream may start at most one minute behind our own timestamp (MAVLink signing spec).
NEW_STREAM_TOLERANCE = 6000 * 1000
_TIMESTAMP = struct.Struct("<IH")  # 48-bit timestamp: low 32 bits, high 16 bits


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
    # pymavlink's own check stores the stream's timestamp before it compares the signature,
    # so one forged datagram with a future timestamp would lock the genuine stream out.
    mav.check_signature = types.MethodType(check_signature_first, mav)  # type: ignore[attr-defined]


def check_signature_first(mav: Any, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """MAVLink 2 signature check that changes no state unless the signature is valid.

    Same rules as pymavlink's ``MAVLink.check_signature`` (the MAVLink signing spec:
    SHA-256 of key + frame, first 6 bytes; per-stream (link, system, component)
    timestamps strictly increase; a new stream at most one minute behind us), in the
    safe order: the signature first, then the timestamp, and only then are the
    stream's timestamp and our own updated.
    """
    signing = mav.signing
    frame = bytes(msgbuf)
    if len(frame) < 13 or signing.secret_key is None:
        return False
    digest = hashlib.sha256(bytes(signing.secret_key) + frame[:-6]).digest()[:6]
    if not hmac.compare_digest(digest, frame[-6:]):
        return False
    low, high = _TIMESTAMP.unpack(frame[-12:-6])
    timestamp = low + (high << 32)
    stream = (frame[-13], src_system, src_component)
    last = signing.stream_timestamps.get(stream)
    if last is not None and timestamp <= last:
        return False  # a replay, or out of order
    if last is None and timestamp + NEW_STREAM_TOLERANCE < signing.timestamp:
        return False  # a new stream from the past
    signing.stream_timestamps[stream] = timestamp
    signing.timestamp = max(signing.timestamp, timestamp)
    return True
