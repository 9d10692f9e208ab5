"""The replay's read-ahead threads (``replay/lookahead.py``) and the network's batches.

References: the network run on one image at a time (``Detector.detect``, itself held to
Ultralytics' predict in test_detection_parity.py) for the batches; the recording's own item
iterator for the order and the errors. The whole replay with and without the look-ahead is
compared in test_recording_replay.py.
"""

import threading
import time

import cv2
import numpy as np
import pytest

from insulator_rs.exceptions import BagError
from insulator_rs.ports.detector import NetworkDetector, open_network_detector
from insulator_rs.ports.sensors import CameraFrame, PoseStamped
from insulator_rs.recording.reader import Item
from insulator_rs.replay.lookahead import Lookahead, LookaheadDetector
from helpers.photos import PHOTOS

BOX_TOL_PX = 1e-3  # a batched convolution may round differently from one image's (0 measured on x86-64)
SCORE_TOL = 1e-5


@pytest.fixture(scope="module")
def network() -> NetworkDetector:
    return open_network_detector("insulator-sim")


def _photos():
    images = [cv2.imread(str(p)) for p in sorted(PHOTOS.glob("*.jpg"))[:5]]
    assert all(i is not None for i in images)
    return images + [cv2.resize(images[0], (700, 400))]  # another letterbox shape: a second run


def _frame(t, image):
    return Item("frame", t, "/camera", CameraFrame(time=t, image=image, camera=None, T_b_c=np.eye(4)))


def _pose(t):
    return Item("pose", t, "/odom", PoseStamped(time=t, T_w_b=np.eye(4)))


def test_a_batch_gives_each_image_its_own_detections(network):
    images = _photos()
    alone = [network.network.detect(i) for i in images]
    batched = network.network.detect_batch(images)
    assert len(batched) == len(images)
    assert sum(len(a) for a in alone) >= 5  # the photos have strings to find
    for i, (a, b) in enumerate(zip(alone, batched)):
        assert len(a) == len(b), i
        np.testing.assert_allclose(b.boxes, a.boxes, atol=BOX_TOL_PX, err_msg=f"image {i}")
        np.testing.assert_allclose(b.scores, a.scores, atol=SCORE_TOL, err_msg=f"image {i}")
        assert list(b.class_ids) == list(a.class_ids)


def test_a_bad_image_in_a_batch_is_named(network):
    with pytest.raises(TypeError, match=r"images\[1\]"):
        network.network.detect_batch([_photos()[0], np.zeros((4, 4, 3), np.float32)])


@pytest.mark.parametrize("workers", [1, 3])
def test_items_come_in_order_with_each_frames_boxes_computed_ahead(network, workers):
    """Network threads finish their chunks out of order; the loop still gets the items in the
    recording's order and each frame its own boxes."""
    images = _photos()
    items = []
    for k in range(3):
        for j, image in enumerate(images):
            t = k * 10 + j
            items += [_pose(t), _frame(t + 0.5, image)]
    ahead = Lookahead(iter(items), network, batch=4, workers=workers)
    detector = ahead.detector()
    assert isinstance(detector, LookaheadDetector) and detector.name == "insulator-sim"
    got = []
    for item in ahead.items():
        got.append(item)
        if item.kind == "frame":
            boxes = detector(item.value.image)
            np.testing.assert_allclose(boxes, network(item.value.image), atol=BOX_TOL_PX)
    assert [(i.kind, i.time) for i in got] == [(i.kind, i.time) for i in items]
    assert ahead.counts["frames_ahead"] == 3 * len(images) and ahead.counts["network_runs"] == 5
    assert ahead.counts["batches_failed"] == 0


def test_skipped_frames_are_passed_over_and_an_unknown_image_runs_the_network(network):
    images = _photos()
    items = [_frame(float(t), images[t % len(images)]) for t in range(8)]
    ahead = Lookahead(iter(items), network, batch=4)
    detector = ahead.detector()
    frames = [i.value for i in ahead.items()]
    # only every third frame asked for (a replay detecting every detect_period s)
    for f in frames[::3]:
        np.testing.assert_allclose(detector(f.image), network(f.image), atol=BOX_TOL_PX)
    other = images[1].copy()
    np.testing.assert_allclose(detector(other), network(other), atol=BOX_TOL_PX)


def test_a_broken_recording_raises_after_what_was_read_before_it(network):
    images = _photos()

    def items():
        for t in range(6):
            yield _frame(float(t), images[t % len(images)])
        raise BagError("flight.mcap: the recording breaks off after /camera at t=5.000 s")

    ahead = Lookahead(items(), network, batch=4)
    detector = ahead.detector()
    got = []
    with pytest.raises(BagError, match="breaks off after /camera"):
        for item in ahead.items():
            got.append(item.time)
            detector(item.value.image)
    assert got == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert ahead.counts["frames_ahead"] == 6  # the frames before the break were detected too


def test_a_failing_batch_leaves_the_error_to_the_loops_own_call(network):
    """A frame the network raises on: the batch is not computed ahead, and the runner's call
    meets the network's own error (counted there as a detector error)."""
    bad = np.zeros((64, 64, 3), np.float32)  # not uint8: the network refuses it
    items = [_frame(0.0, _photos()[0]), _frame(1.0, bad)]
    ahead = Lookahead(iter(items), network, batch=4)
    detector = ahead.detector()
    frames = [i.value for i in ahead.items()]
    assert ahead.counts["batches_failed"] == 1 and ahead.counts["frames_ahead"] == 0
    np.testing.assert_allclose(detector(frames[0].image), network(frames[0].image), atol=BOX_TOL_PX)
    with pytest.raises(TypeError, match="uint8"):
        detector(frames[1].image)


def test_without_a_network_it_only_reads_ahead():
    items = [_pose(float(t)) for t in range(1000)]
    ahead = Lookahead(iter(items), None)
    assert ahead.detector() is None
    assert [i.time for i in ahead.items()] == [i.time for i in items]


def test_a_replay_that_stops_early_stops_the_reader(network):
    """The loop leaves after one item (an interrupted replay): the reader thread ends instead
    of blocking on its full queue for ever."""
    def endless():
        t = 0.0
        while True:
            t += 1.0
            yield _pose(t)

    ahead = Lookahead(endless(), network, depth=1)
    stream = ahead.items()
    next(stream)
    stream.close()  # the generator's exit closes the look-ahead
    deadline = time.monotonic() + 10
    while any(t.name.startswith("replay-lookahead") and t.is_alive() for t in threading.enumerate()):
        assert time.monotonic() < deadline, "the reader thread did not stop"
        time.sleep(0.05)


@pytest.mark.parametrize("arg", ["batch", "depth", "workers"])
def test_bad_sizes_are_refused_by_name(arg):
    with pytest.raises(ValueError, match=arg):
        Lookahead(iter([]), None, **{arg: 0})
