"""The degraded-camera study (issue 47 item 4): its decorators on the detector port, and one
small-scene cell flown end to end.

References: numpy's own statistics of the frames (the RMS contrast a haze leaves is stated in
closed form), the binomial spread of the drops, and the scene's ground truth (scoring)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from insulator_rs.sim.camera_degradation import (DroppedTrueBoxes, HazedFrames, TRUE_BOX_SLACK_PX, haze_frame,
                                                 on_true_boxes)


def _frame(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(40, 200, size=(60, 80, 3)).astype(np.uint8)


@pytest.mark.parametrize(("haze", "contrast"), [(0.5, 1.0), (0.0, 0.6), (0.5, 0.6), (0.8, 0.35)])
def test_haze_scales_the_rms_contrast_as_stated(haze, contrast):
    img = _frame()
    out = haze_frame(img, haze=haze, contrast=contrast)
    assert out.dtype == np.uint8 and out.shape == img.shape
    # RMS contrast (std of the pixels) times (1 - haze) * contrast, up to the 8-bit rounding
    assert float(out.std()) == pytest.approx((1 - haze) * contrast * float(img.std()), abs=0.3)
    # the mean moves toward the air light: (1 - haze) * mean + haze * A (the stretch keeps the mean)
    assert float(out.mean()) == pytest.approx((1 - haze) * float(img.mean()) + haze * 220.0, abs=0.5)


def test_haze_refuses_bad_arguments_by_name():
    img = _frame()
    with pytest.raises(ValueError, match="haze"):
        haze_frame(img, haze=1.0, contrast=1.0)
    with pytest.raises(ValueError, match="contrast"):
        haze_frame(img, haze=0.1, contrast=0.0)
    with pytest.raises(ValueError, match="image"):
        haze_frame(img.astype(np.float32), haze=0.1, contrast=1.0)
    with pytest.raises(ValueError, match="contrast"):
        HazedFrames(lambda im: np.zeros((0, 5)), haze=0.1, contrast=float("nan"))


def test_hazed_frames_hand_the_network_the_hazed_frame():
    seen = []

    def network(image):
        seen.append(image)
        return np.zeros((0, 5))

    img = _frame()
    HazedFrames(network, haze=0.5, contrast=0.6)(img)
    np.testing.assert_array_equal(seen[0], haze_frame(img, haze=0.5, contrast=0.6))


TRUTH = {7: (10.0, 10.0, 14.0, 40.0), 9: (50.0, 5.0, 56.0, 30.0)}
# two boxes on the strings (one a pixel off sideways: IoU under 0.5, still on it), one on steel
BOXES = np.array([[11.0, 11.0, 15.0, 39.0, 0.8], [51.0, 6.0, 57.0, 31.0, 0.7], [30.0, 30.0, 40.0, 40.0, 0.6]])


def test_a_box_is_on_a_true_string_when_its_centre_is_in_the_true_box():
    np.testing.assert_array_equal(on_true_boxes(BOXES, list(TRUTH.values())), [True, True, False])
    shifted = BOXES[:1].copy()
    shifted[0, [0, 2]] += 4.0 + TRUE_BOX_SLACK_PX + 0.1  # centre beyond the slack
    assert not on_true_boxes(shifted, list(TRUTH.values())).any()
    assert on_true_boxes(np.zeros((0, 5)), list(TRUTH.values())).shape == (0,)


@pytest.mark.parametrize("fraction", [0.5, 0.8])
def test_drops_true_boxes_at_the_rate_seeded_and_never_others(fraction):
    def network(image):
        return BOXES.copy()

    frames = 2000
    runs = []
    for _ in range(2):
        d = DroppedTrueBoxes(network, lambda image: TRUTH, fraction=fraction, seed=3)
        kept = [d(np.zeros((1, 1, 3), np.uint8)) for _ in range(frames)]
        runs.append(kept)
        assert d.counts["true_boxes"] == 2 * frames and d.counts["other_boxes"] == frames
        # binomial: 4 standard deviations of 4000 draws
        n = 2 * frames
        assert abs(d.counts["dropped"] / n - fraction) < 4 * np.sqrt(fraction * (1 - fraction) / n)
        assert all(any(np.array_equal(b, BOXES[2]) for b in k) for k in kept)  # the steel box always passes
    assert all(np.array_equal(a, b) for a, b in zip(*runs))  # the same seed drops the same boxes
    other = DroppedTrueBoxes(network, lambda image: TRUTH, fraction=fraction, seed=4)
    assert any(not np.array_equal(a, other(np.zeros((1, 1, 3), np.uint8))) for a in runs[0])


def test_drop_fraction_is_checked_by_name():
    with pytest.raises(ValueError, match="fraction"):
        DroppedTrueBoxes(lambda im: BOXES, lambda im: TRUTH, fraction=1.5, seed=0)


@pytest.mark.slow
def test_one_small_scene_cell_flies_end_to_end(tmp_path):
    """The small scene (two strings) at 80 % dropped boxes with the cue on: the flight ends, the
    drops bit, and what the cell reports agrees with the scene's truth as scored."""
    from helpers.flights import small_scene

    from insulator_rs.evaluation.degraded_camera_study import fly_cell, write_results

    scene, mission = small_scene(tmp_path)
    cell = fly_cell("B", "drop80", True, tmp_path / "flight", scene=scene, mission_path=mission)
    print(cell)
    assert cell.status == "finished"
    assert cell.strings == 2
    assert cell.true_boxes and cell.dropped_boxes is not None
    assert 0.6 < cell.dropped_boxes / cell.true_boxes < 0.95
    score = json.loads((tmp_path / "flight" / "score.json").read_text(encoding="utf-8"))
    assert cell.found == score["insulators_matched"]
    assert cell.photographed <= cell.found
    assert cell.false_finds == score["insulators_found"] - score["insulators_matched"]
    write_results(tmp_path / "out", [cell], seed=0)
    assert (tmp_path / "out" / "degraded_camera.png").stat().st_size > 0
    table = (tmp_path / "out" / "degraded_camera.md").read_text(encoding="utf-8")
    assert f"| {cell.found}/2 | {cell.photographed}/2 | {cell.false_finds} |" in table


def _cell(tower, condition, cue, found):
    from insulator_rs.evaluation.degraded_camera_study import DegradedCell

    return DegradedCell(tower=tower, condition=condition, cue=cue, strings=4, found=found, photographed=found,
                        false_finds=0, flight_time_s=700.0, status="finished", detector="net", true_boxes=10,
                        dropped_boxes=8, lidar_looks=0, wall_s=1.0)


def test_resume_keeps_the_cells_flown_and_refuses_another_seed(tmp_path, monkeypatch):
    from insulator_rs.evaluation import degraded_camera_study as study

    flown = [_cell("B", "drop80", "camera only", 3), _cell("B", "drop80", "camera + LiDAR", 4),
             _cell("A", "haze", "camera only", 9)]
    study.write_results(tmp_path, flown, seed=5)

    def no_flight(*args, **kwargs):
        raise AssertionError("a kept cell was flown again")

    monkeypatch.setattr(study, "fly_cell", no_flight)
    cells = study.run_study(tmp_path, ["B"], ["drop80"], seed=5, resume=True, say=lambda _: None)
    assert cells == flown[:2]
    assert study.flown_cells(tmp_path) == flown  # the cell of another tower stays in the table
    table = (tmp_path / "degraded_camera.md").read_text(encoding="utf-8")
    assert "| B | 80 % of true boxes dropped | 3/4 | 3/4 | 0 | 700 | 4/4 | 4/4 | 0 | 700 |" in table
    with pytest.raises(ValueError, match="seed"):
        study.run_study(tmp_path, ["B"], ["drop80"], seed=6, resume=True, say=lambda _: None)
