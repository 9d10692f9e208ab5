"""UAV photometric augmentations: closed-form references for haze and flare, blur keeps brightness, boxes untouched."""

from __future__ import annotations

import random

import numpy as np

from insulator_rs.detection.uav_augment import UavPhotometric, haze, motion_or_defocus_blur, sun_flare


def test_haze_is_koschmieder() -> None:
    img = np.array([[[0, 100, 200]]], np.uint8)
    out = haze(img, airlight=220.0, density=0.25)
    np.testing.assert_array_equal(out, [[[55, 130, 205]]])  # 0.75 * I + 0.25 * 220


def test_sun_flare_peaks_at_its_centre_and_fades() -> None:
    img = np.full((101, 101, 3), 50, np.uint8)
    out = sun_flare(img, centre=(50.0, 50.0), radius=10.0, strength=100.0).astype(int)
    np.testing.assert_array_equal(out[50, 50], [135, 145, 150])  # 50 + 100 * tint (B 0.85, G 0.95, R 1.0)
    assert (out[0, 0] == 50).all() and out[50, 60, 2] < out[50, 55, 2] < out[50, 50, 2]


def test_blur_keeps_mean_brightness_and_shape() -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (64, 80, 3), dtype=np.uint8)
    random.seed(1)
    for _ in range(6):
        out = motion_or_defocus_blur(img)
        assert out.shape == img.shape and out.dtype == np.uint8
        assert abs(float(out.mean()) - float(img.mean())) < 2.0
        assert out.std() < img.std()  # it did blur


def test_augment_changes_pixels_only() -> None:
    random.seed(0)
    img = np.full((48, 64, 3), 120, np.uint8)
    img[10:20, 10:30] = 250
    boxes = np.array([[10.0, 10.0, 30.0, 20.0]])
    labels = {"img": img.copy(), "bboxes": boxes.copy()}
    out = UavPhotometric(p_blur=1.0, p_haze=1.0, p_flare=1.0)(labels)
    assert out["img"].shape == img.shape and out["img"].dtype == np.uint8 and not np.array_equal(out["img"], img)
    np.testing.assert_array_equal(out["bboxes"], boxes)
    untouched = UavPhotometric(0.0, 0.0, 0.0)({"img": img.copy()})
    np.testing.assert_array_equal(untouched["img"], img)
