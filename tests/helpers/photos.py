"""The committed real photos of insulators with their VOC labels (``tests/data/photos``)."""

from __future__ import annotations

from pathlib import Path

PHOTOS = Path(__file__).parents[1] / "data" / "photos"
