"""A string boxed in parts is judged on its parts together (perception/box_groups.py).

Reference: boxes drawn by hand in pixel coordinates (what they group into is read off the
drawing), and the pipeline's own scale check on a known geometry."""

from __future__ import annotations

import numpy as np

from insulator_rs.perception.box_groups import string_boxes


def test_parts_of_one_string_are_united_and_other_boxes_kept() -> None:
    boxes = np.array([
        [100, 50, 107, 84, 0.7],   # a string's upper part (7 x 34)
        [101, 80, 108, 110, 0.5],  # its lower part, overlapping
        [99, 60, 106, 85, 0.3],    # a third box on the same string
        [200, 50, 207, 90, 0.6],   # another string, another column
        [120, 120, 160, 126, 0.4],  # a wide (tension) box: not joined to the tall ones
    ], dtype=float)
    whole = string_boxes(boxes)
    np.testing.assert_array_equal(whole[:3], [[99, 50, 108, 110]] * 3)
    np.testing.assert_array_equal(whole[3:], boxes[3:, :4])


def test_a_gap_along_the_string_joins_within_half_the_shorter_part() -> None:
    upper = [10, 0, 16, 30]
    near = [10, 40, 16, 60]  # a 10 px gap, shorter part 20 px: joined
    far = [10, 75, 16, 95]  # a 15 px gap after ``near``, shorter 20 px: not
    whole = string_boxes(np.array([upper, near, far], dtype=float))
    np.testing.assert_array_equal(whole[0], [10, 0, 16, 60])
    np.testing.assert_array_equal(whole[2], far)
    # side by side, overlapping by less than half the narrower: two strings, not one
    apart = string_boxes(np.array([[10, 0, 16, 30], [14, 0, 20, 30]], dtype=float))
    np.testing.assert_array_equal(apart, [[10, 0, 16, 30], [14, 0, 20, 30]])


def test_wide_parts_group_along_x() -> None:
    whole = string_boxes(np.array([[0, 10, 30, 16], [25, 11, 60, 17]], dtype=float))
    np.testing.assert_array_equal(whole, [[0, 10, 60, 17]] * 2)


def test_no_box_and_one_box() -> None:
    assert string_boxes(np.zeros((0, 5))).shape == (0, 4)
    np.testing.assert_array_equal(string_boxes(np.array([[1.0, 2.0, 3.0, 9.0]])), [[1, 2, 3, 9]])


def test_a_part_of_a_string_passes_the_scale_check_beside_the_rest_of_it() -> None:
    """The pipeline's scale check: a string of the mission's length, localized whole, boxed by
    a part of 60 % of its span and a second part: alone, the part is refused (implausible, ratio
    1.67 > 1.5); with the other part in the same frame, the two together span it."""
    from insulator_rs.perception.pipeline import PerceptionPipeline
    from insulator_rs.rig import simulator_rig

    import insulator_rs as ir

    rig = simulator_rig()
    pipe = PerceptionPipeline(rig.camera, rig.T_b_c, rig.T_b_l, insulator_length=2.0)
    T_c_w = np.eye(4)
    center, axis = np.array([0.0, 0.0, 12.0]), np.array([0.0, 1.0, 0.0])  # 12 m ahead, vertical in the image
    uv, _ = ir.project_points(np.stack([center - axis, center + axis]), T_c_w, rig.camera)
    (u0, v0), (u1, v1) = uv
    part = np.array([u0 - 3, v0, u0 + 3, v0 + 0.6 * (v1 - v0)])
    rest = np.array([u0 - 3, v0 + 0.55 * (v1 - v0), u0 + 3, v1])
    assert not pipe._scale_plausible(center, axis, part, T_c_w, rig.camera)
    whole = string_boxes(np.stack([part, rest]))
    assert pipe._scale_plausible(center, axis, whole[0], T_c_w, rig.camera)
