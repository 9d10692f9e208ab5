"""Hard negatives from labelled photos (detection/negatives.py, ``detect negatives``): the tiles
kept hold no labelled box (checked pixel by pixel against a mask of the boxes), and every box a
detector draws on them is counted per threshold."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.photos import PHOTOS

from insulator_rs.app.cli import main
from insulator_rs.detection.evaluate import LabelledImage
from insulator_rs.detection.negatives import MARGIN_PX, count_negative_false_boxes, negative_tiles


def _photo(tmp_path: Path, boxes: list[list[float]], w: int = 640, h: int = 480) -> LabelledImage:
    path = tmp_path / f"p{len(list(tmp_path.glob('*.png')))}.png"
    img = np.full((h, w, 3), 90, np.uint8)
    cv2.imwrite(str(path), img)
    return LabelledImage(path, np.asarray(boxes, dtype=np.float64).reshape(-1, 4), ("insulator",) * len(boxes))


def test_kept_tiles_stay_clear_of_every_box_and_cover_the_rest(tmp_path: Path) -> None:
    boxes = [[300.0, 100.0, 360.0, 300.0], [20.0, 400.0, 120.0, 470.0]]
    sample = _photo(tmp_path, boxes)
    tiles = negative_tiles([sample])
    assert tiles and all(t.side == 240 for t in tiles)
    grown = np.zeros((480, 640), bool)  # reference: the boxes grown by the margin, as a mask
    for x1, y1, x2, y2 in boxes:
        grown[max(0, int(y1) - MARGIN_PX):int(y2) + MARGIN_PX, max(0, int(x1) - MARGIN_PX):int(x2) + MARGIN_PX] = True
    for t in tiles:
        assert not grown[t.y0:t.y0 + t.side, t.x0:t.x0 + t.side].any()
    # the grid (stride 120, last row/column flush): every position whose tile misses the mask is kept
    xs, ys = sorted({*range(0, 401, 120), 400}), sorted({*range(0, 241, 120), 240})
    clear = {(x, y) for y in ys for x in xs if not grown[y:y + 240, x:x + 240].any()}
    assert {(t.x0, t.y0) for t in tiles} == clear
    assert negative_tiles([_photo(tmp_path, [[0.0, 0.0, 640.0, 480.0]])]) == []


def test_every_box_on_a_negative_tile_is_counted_per_threshold(tmp_path: Path) -> None:
    tiles = negative_tiles([_photo(tmp_path, [])])
    calls = []

    def detect(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        calls.append(image.shape)
        k = len(calls) % 3  # 1, 2, 0, 1, 2, 0 ... boxes
        return np.tile([[5.0, 5.0, 50.0, 50.0]], (k, 1)), np.array([0.3, 0.6][:k])

    c = count_negative_false_boxes(detect, tiles, thresholds=(0.5, 0.25))
    # 640x480, 240 px tiles at a 120 px stride: 5 columns (the last flush at x 400) x 3 rows
    assert all(s == (240, 240, 3) for s in calls) and c.tiles == len(tiles) == 15
    assert c.false_boxes == {0.25: 15, 0.5: 5} and c.tiles_with_false_box == {0.25: 10, 0.5: 5}
    d = c.to_dict()
    assert d["score>=0.25"]["false_boxes_per_tile"] == 1.0 and len(d["false_boxes_at_lowest_threshold"]) == 15
    with pytest.raises(ValueError, match="tile_fraction"):
        negative_tiles([], tile_fraction=2.0)


def test_detect_negatives_on_the_committed_photos(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """The command on the repository's labelled photos with a shipped model; a folder without
    labels is refused by name, without a traceback."""
    photos = tmp_path / "photos"  # one labelled photo with 3 clear tiles (the suite runs under qemu too)
    photos.mkdir()
    first = next(PHOTOS.glob("0718_*.jpg"))
    for f in (first, first.with_suffix(".xml")):
        (photos / f.name).write_bytes(f.read_bytes())
    out = tmp_path / "neg.json"
    assert main(["detect", "negatives", str(photos), "--model", "insulator-real", "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["negative_tiles"] == 3 and d["photos"] == 1 and "score>=0.25" in d and "score>=0.5" in d
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["detect", "negatives", str(empty)]) == 2
    assert "empty" in capsys.readouterr().err
