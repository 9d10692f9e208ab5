"""The photo check's shed-pattern cue (``perception/shed_pattern.py``). Reference: images drawn
here with OpenCV whose string is known by construction: a row of sheds (bright discs) at a given
pitch along a vertical axis, over a background that turns from sky to ground halfway (where the
shipped network stops boxing), ending at a known row; the cue must extend the boxed stretch
as far as the sheds go (to within a period of their end, where the window holds half string,
half beyond), and not past them."""

from __future__ import annotations

import numpy as np
import pytest

from insulator_rs.perception.shed_pattern import axis_profile, shed_evidence

H, W = 1200, 400
U = 200  # px: the string's column
DIAMETER = 60.0  # px: shed diameter
PITCH = 30  # px: shed pitch


def photo(first_row: int, last_row: int, *, background_split: int = 600, lattice: bool = False) -> np.ndarray:
    """Grey image: sky above ``background_split``, ground below, sheds from ``first_row`` to
    ``last_row`` (rows of their centres); ``lattice``: a row of crossbars at the shed pitch apart
    from the string (below it), which a periodicity test alone would take for sheds."""
    rng = np.random.default_rng(7)
    img = np.empty((H, W), np.float32)
    img[:background_split] = 200.0
    img[background_split:] = 90.0
    img += rng.normal(0.0, 2.0, img.shape).astype(np.float32)
    img[first_row:last_row, U - 4:U + 5] = 120.0  # the core rod
    for row in range(first_row, last_row + 1, PITCH):
        half = int(DIAMETER / 2) if (row - first_row) // PITCH % 2 == 0 else int(DIAMETER / 3)
        img[row - 4:row + 4, U - half:U + half + 1] = 160.0  # a shed seen edge-on
    if lattice:
        for row in range(last_row + 150, H, PITCH):
            img[row - 3:row + 3, U - 40:U + 41] = 140.0
    return img


def samples(top: float, bottom: float, n: int = 41) -> np.ndarray:
    return np.stack([np.full(n, float(U)), np.linspace(top, bottom, n)], axis=1)


def boxed_above(uv: np.ndarray, row: float) -> np.ndarray:
    return uv[:, 1] < row


def test_the_profile_repeats_at_the_shed_pitch_and_is_nan_outside_the_image() -> None:
    img = photo(100, 1100)
    uv = samples(100, 1100)
    profile, at = axis_profile(img, uv, DIAMETER, 200.0)
    assert at[0] == pytest.approx(200.0) and at[-1] == pytest.approx(1200.0)
    assert np.isnan(profile[:100]).all() and np.isnan(profile[-100:]).all()  # rows -100 .. -1, 1200 ..
    inner = profile[400:1200]
    lags = np.arange(10, 90)
    r = [np.corrcoef(inner[:-k], inner[k:])[0, 1] for k in lags]
    assert lags[int(np.argmax(r))] == 2 * PITCH  # big and small sheds alternate: the period is two pitches


def test_the_sheds_past_the_boxed_stretch_count_where_the_ground_lies_behind_them() -> None:
    img = photo(100, 1100)
    uv = samples(100, 1100)
    boxed = boxed_above(uv, 600)  # the network's boxes stop where the ground begins
    out = shed_evidence(img, uv, boxed, DIAMETER)
    assert out[uv[:, 1] <= 1100 - 2 * PITCH].all()  # to within a period (two pitches) of the end


def test_the_evidence_stops_where_the_string_does() -> None:
    """The projection runs 250 px past the string's true end (a gimbal off in pitch): the samples
    beyond the last shed are not the string's."""
    img = photo(100, 850)
    uv = samples(100, 1100)
    out = shed_evidence(img, uv, boxed_above(uv, 600), DIAMETER)
    past = uv[:, 1] > 850 + 2 * PITCH
    assert out[uv[:, 1] <= 820].all() and not out[past].any()


def test_a_repetition_apart_from_the_string_is_not_the_string() -> None:
    img = photo(100, 700, lattice=True)
    uv = samples(100, 1100)
    out = shed_evidence(img, uv, boxed_above(uv, 500), DIAMETER)
    assert not out[uv[:, 1] > 760].any()  # the crossbars from row 850 on repeat at the pitch too


def test_without_a_box_or_a_pattern_nothing_is_added() -> None:
    uv = samples(100, 1100)
    img = photo(100, 1100)
    assert not shed_evidence(img, uv, np.zeros(len(uv), bool), DIAMETER).any()
    flat = np.full((H, W), 128.0, np.float32)
    boxed = boxed_above(uv, 600)
    assert np.array_equal(shed_evidence(flat, uv, boxed, DIAMETER), boxed)


def test_a_string_projected_far_out_of_the_frame_costs_no_more_than_the_frame() -> None:
    """A string seen from near the camera's plane projects millions of pixels out of the frame:
    only the stretch whose strip meets the image is sampled (a strip along all of it would not
    fit in memory), and the samples inside are judged as before."""
    img = photo(100, 1100)
    uv = samples(100, 1100)
    boxed = boxed_above(uv, 600)
    inside = shed_evidence(img, uv, boxed, DIAMETER)
    far = np.vstack([uv, [[float(U), 3.0e7]]])  # one more sample, 30 million pixels down
    profile, _ = axis_profile(img, far, DIAMETER, 200.0)
    assert len(profile) < H + 2 * (200 + DIAMETER) + 3
    out = shed_evidence(img, far, np.append(boxed, False), DIAMETER)
    assert out.shape == (len(far),) and not out[-1]
    assert np.array_equal(out[:-2], inside[:-1])  # the last sample before the far one now lies on a 30-million-pixel segment


@pytest.mark.parametrize("diameter", [float("nan"), 2.0, 1.0e6])
def test_a_diameter_too_small_too_large_or_undefined_adds_nothing(diameter: float) -> None:
    img = photo(100, 1100)
    uv = samples(100, 1100)
    boxed = boxed_above(uv, 600)
    assert np.array_equal(shed_evidence(img, uv, boxed, diameter), boxed)


def test_a_string_wholly_outside_the_frame_adds_nothing() -> None:
    img = photo(100, 1100)
    uv = samples(100, 1100) + np.array([5000.0, 0.0])
    boxed = np.zeros(len(uv), bool)
    boxed[:5] = True
    assert np.array_equal(shed_evidence(img, uv, boxed, DIAMETER), boxed)
