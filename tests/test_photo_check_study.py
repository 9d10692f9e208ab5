"""The photo check's rates against the ground truth (evaluation/photo_check_study.py), on a small
sample: the small scene's two strings, each shot from 6 m at the inspection camera's zoom that
frames it (rendered at photo scale 0.3: 1200x900 px, 1.85 mm/px, inspection-grade by the truth),
then made bad by a gimbal offset, a wrong zoom and motion blur.

Reference: the scene's ground truth (``InsulatorTruth``) projected through each photo's *true*
pose and intrinsics (``photo_coverage.string_in_photo``: span share and mm/px;
``photo_quality.whole_in_frame``), never the check's own figures; the gimbal variant is also
rendered by the ray caster at its true pose, and the warp the study uses instead agrees with it.
The check runs the shipped ``insulator-sim`` network at ``PHOTO_DETECT_CONF``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from helpers.flights import small_scene
from insulator_rs.evaluation.photo_check_study import (MAX_GOOD_UNFIT, MIN_BAD_UNFIT, ZOOM_FACTORS, StringTruth,
                                                       format_table,
                                                       gimbal_offset, inspection_grade, judge, rates,
                                                       ray_cast_renderer, study_photo, wrong_zoom)
from insulator_rs.flight.gimbal import aim_at
from insulator_rs.perception.photo_check import PHOTO_DETECT_CONF
from insulator_rs.ports.detector import open_network_detector
from insulator_rs.poses import pose_from_yaw
from insulator_rs.rig import simulator_rig
from insulator_rs.sim.sensors import SimulatedSensors
from insulator_rs.sim.towers import load_tower

FOCAL_PX = 10_800.0  # full resolution: the 1.5 m string over ~2700 of 3000 px from 6 m
SCALE = 0.3
LOCALIZATION_ERROR = np.array([0.03, -0.02, 0.04])  # m: the flight's localized centre is off by this
ZOOMED_IN = {f"focal x{f:g}" for f in ZOOM_FACTORS if f > 1}


# A study (renders and the network on each variant): the --all tier.
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    scene, _ = small_scene(tmp_path_factory.mktemp("scene"))
    tower = load_tower(scene)
    rig = simulator_rig()
    cam = rig.inspection_camera()
    out = []
    for truth in tower.insulators:
        T_w_b = pose_from_yaw(truth.center + np.array([6.0 * np.sign(truth.center[0]), 0.0, 0.0]),
                              0.0 if truth.center[0] < 0 else math.pi)
        sensors = SimulatedSensors(tower.mesh, lambda t, T=T_w_b: T, rig, photo_scale=SCALE)
        _, _, T_b_c = aim_at(T_w_b, cam.T_b_c, truth.center, cam.gimbal)
        frame = sensors.photo(0.0, T_b_c, camera=cam.at_focal(FOCAL_PX))
        out.append((frame.image, frame.camera, T_w_b @ T_b_c,
                    StringTruth(np.asarray(truth.center), np.asarray(truth.axis), float(truth.length))))
    return tower, out


@pytest.fixture(scope="module")
def detector():
    return open_network_detector("insulator-sim", conf=PHOTO_DETECT_CONF, threads=1)


@pytest.fixture(scope="module")
def rows(shots, detector):
    _, photos = shots
    truths = [t for *_, t in photos]
    out = []
    for i, (image, camera, T_w_c, truth) in enumerate(photos):
        assert inspection_grade(camera, T_w_c, truth)[0]  # the sample is what it says, by the truth
        out += study_photo(detector, "small", f"shot {i}", image, camera, T_w_c, truth.center + LOCALIZATION_ERROR,
                           1.5, truths)
    print(format_table(out))
    for r in out:
        print(r.kind, r.perturbation, r.grade, r.fit, r.reasons, f"{r.coverage:.2f} {r.blur_extent:.3f}")
    return out


def test_good_photos_are_fit_and_gimbal_blur_and_zoom_out_unfit(rows):
    k = rates(rows)
    assert k["good"] == 2 and k["good_unfit"] <= MAX_GOOD_UNFIT and k["retakes"] == 0.0
    caught = [r for r in rows if not r.grade and not (r.kind == "zoom" and r.perturbation in ZOOMED_IN)]
    assert len(caught) >= 16 and rates(caught)["bad_unfit"] >= MIN_BAD_UNFIT
    assert all(n > 0 for n, _ in (k["bad_unfit_by_kind"][x] for x in ("gimbal", "zoom", "blur")))
    # a gimbal panned a few degrees leaves the string whole and sharp (the truth: inspection-grade),
    # but not where the flight believes it is: unfit, a retake aims again
    assert all(not r.fit for r in rows if r.kind == "gimbal" and r.grade)


@pytest.mark.xfail(strict=True, reason="known gap: a zoom in (the string larger than planned, cut by the border "
                   "at both ends) leaves no evidence the close-up network gives reliably (its boxes stop short "
                   "of the border, shed widths vary 0.8-1.2x)")
def test_a_zoom_in_is_unfit(rows):
    zoomed_in = [r for r in rows if r.kind == "zoom" and r.perturbation in ZOOMED_IN]
    assert zoomed_in and all(not r.grade for r in zoomed_in) and all(not r.fit for r in zoomed_in)


def test_the_warped_gimbal_offset_is_judged_as_the_rendered_one(shots, detector):
    """The study's homography stands in for a render: a pitch of 4 degrees rendered by the ray
    caster at the true pose and the warped photo get the same verdict, and the truth calls it bad."""
    tower, photos = shots
    image, camera, T_w_c, truth = photos[0]
    warped, T_true = gimbal_offset(image, camera, T_w_c, "pitch", 4.0)
    rendered = ray_cast_renderer(tower.mesh)(camera, T_true)
    assert not inspection_grade(camera, T_true, truth)[0]
    a = judge(detector, warped, camera, T_w_c, truth.center, truth.axis, 1.5)
    b = judge(detector, rendered, camera, T_w_c, truth.center, truth.axis, 1.5)
    assert not a.fit and not b.fit and a.reasons == b.reasons
    # inside the band both saw, the warp is the render up to the renderer's noise and resampling
    band = slice(int(0.1 * camera.height), int(0.8 * camera.height))
    diff = np.abs(warped[band].astype(float) - rendered[band].astype(float))
    assert np.median(diff) < 6.0
    zoomed_in, true_cam = wrong_zoom(image, camera, 1.25)
    assert not inspection_grade(true_cam, T_w_c, truth)[0]
    assert not judge(detector, zoomed_in, camera, T_w_c, truth.center, truth.axis, 1.5).fit
