"""Safety volumes: exact segment-vs-box checks against a dense-sampling reference."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs.geodesy import line_frame
from insulator_rs.planning.safety import OrientedBox, safety_volumes

BOX = OrientedBox(center=np.array([1.0, -2.0, 3.0]),
                  axes=np.array([[np.cos(0.4), np.sin(0.4), 0.0], [-np.sin(0.4), np.cos(0.4), 0.0],
                                 [0.0, 0.0, 1.0]]),
                  half_extents=np.array([3.0, 1.5, 2.0]), name="test box")

coord = st.floats(-8, 8, allow_nan=False)
point = st.tuples(coord, coord, coord).map(np.array)


@settings(max_examples=300, deadline=None)
@given(p0=point, p1=point)
def test_segment_box_matches_dense_sampling(p0, p1):
    """Reference: 20001 samples along the segment tested point-in-box. A sample inside the box
    implies an exact hit; an exact hit implies a sample inside the box grown by the sample
    spacing (so the exact test is neither too strict nor too lenient)."""
    t = np.linspace(0.0, 1.0, 20001)[:, None]
    samples = p0 + t * (p1 - p0)
    spacing = np.linalg.norm(p1 - p0) / 20000
    exact = bool(BOX.segments_intersect(p0[None], p1[None])[0])
    if np.any(BOX.contains(samples)):
        assert exact
    if exact:
        assert np.any(BOX.contains(samples, inflate=spacing + 1e-9))


def test_axis_parallel_and_degenerate_segments():
    inside = BOX.center
    outside = BOX.center + 10 * BOX.axes[0]
    assert BOX.segments_intersect(inside[None], inside[None])[0]
    assert not BOX.segments_intersect(outside[None], outside[None])[0]
    # parallel to an axis, passing just beside the box / grazing it
    off = BOX.center + (BOX.half_extents[1] + 0.01) * BOX.axes[1]
    assert not BOX.segments_intersect((off - 10 * BOX.axes[0])[None], (off + 10 * BOX.axes[0])[None])[0]
    assert BOX.segments_intersect((off - 10 * BOX.axes[0])[None], (off + 10 * BOX.axes[0])[None],
                                  inflate=0.02)[0]


def make_volumes():
    lf = line_frame(np.array([[0.0, -280.0, 0.0], [0.0, 300.0, 1.5]]))
    return lf, safety_volumes(lf, max_width=10.0, max_height=31.0, margin=2.0)


def test_volumes_split_the_sides_and_leave_the_top_open():
    lf, vol = make_volumes()
    plus = np.array([14.0, 0.0, 15.0])   # lateral = +x for a northward line
    minus = np.array([-14.0, 0.0, 15.0])
    assert lf.side(plus) == 1 and lf.side(minus) == -1
    assert vol.points_clear(np.stack([plus, minus])).all()
    assert not vol.segments_clear(plus[None], minus[None])[0]          # straight through the tower
    assert not vol.segments_clear(plus[None], (minus + [0, 100.0, 0])[None])[0]  # through the corridor
    over = np.array([plus, plus + [0, 0, 21.0], minus + [0, 0, 21.0], minus])  # up, over, down
    assert vol.polyline_clear(over)
    assert not vol.polyline_clear(over - [0, 0, 3.0])                   # too low over the top
    assert not vol.points_clear(np.array([[0.0, -150.0, 5.0]]))[0]     # in the conductor corridor
    assert not vol.points_clear(np.array([[0.0, 0.0, -5.0]]))[0]       # under the tower
    assert vol.top == pytest.approx(33.0)


def test_samples_clear_grows_the_boxes_by_half_a_step():
    _, vol = make_volumes()
    near = np.array([[7.5, 0.0, 10.0]])  # 0.5 m outside the box face at lateral 7
    assert vol.samples_clear(near, max_step=0.9)
    assert not vol.samples_clear(near, max_step=1.1)
    with pytest.raises(ValueError, match="max_step"):
        vol.samples_clear(near, max_step=-1.0)
