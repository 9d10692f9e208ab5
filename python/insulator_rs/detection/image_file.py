"""Read one photo for the detector, refusing what would give a silently wrong answer.

OpenCV decodes a truncated JPEG without an error (libjpeg only prints
"Premature end of JPEG file" and fills the rest grey), so the detector would
report "0 detections" for half a photo. :func:`read_image` checks that a JPEG's
entropy-coded data is terminated: the last End-Of-Image marker (FF D9) must
follow the last Start-Of-Scan marker (FF DA); an EXIF thumbnail's own FF D9
lies before the main scan and does not count. 16-bit images (PNG/TIFF) are
refused rather than scaled by a guessed range; the network was trained on
8-bit photos.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from insulator_rs.detection.detector import as_bgr_uint8
from insulator_rs.exceptions import ImageError

JPEG_SOI = b"\xff\xd8"
JPEG_SOS = b"\xff\xda"
JPEG_EOI = b"\xff\xd9"


def jpeg_is_complete(data: bytes) -> bool:
    """True when JPEG bytes hold a scan that ends with an End-Of-Image marker."""
    sos = data.rfind(JPEG_SOS)
    return sos >= 0 and data.rfind(JPEG_EOI) > sos


def read_image(path: Path) -> np.ndarray:
    """The image at ``path`` as BGR uint8 (gray and BGRA converted).

    Raises ImageError naming the file: missing or a directory, not decodable,
    a truncated JPEG, or a pixel depth other than 8 bits.
    """
    path = Path(path)
    if path.is_dir():
        raise ImageError(f"image {path}: is a directory, not an image file")
    try:
        data = path.read_bytes()
    except FileNotFoundError as exc:
        raise ImageError(f"image {path}: no such file") from exc
    except OSError as exc:
        raise ImageError(f"image {path}: cannot be read ({exc.strerror or exc})") from exc
    if data.startswith(JPEG_SOI) and not jpeg_is_complete(data):
        raise ImageError(f"image {path}: truncated JPEG (no end-of-image marker after the scan data)")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageError(f"cannot read image {path}: not a decodable image (OpenCV could not decode its {len(data)} bytes)")
    if image.dtype != np.uint8:
        bits = image.dtype.itemsize * 8
        raise ImageError(f"image {path}: {bits}-bit pixels ({image.dtype}) are not supported; "
                         "the detector takes 8-bit images (convert, e.g. with a tone map)")
    try:
        return as_bgr_uint8(image, name=f"image {path}")
    except (TypeError, ValueError) as exc:
        raise ImageError(str(exc)) from exc
