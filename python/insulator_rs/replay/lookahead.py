"""Read a recording ahead of the replay in a thread: decoding, and the network's boxes for its
frames, run in batches.

The replay's loop (clock, pairing, pipeline, registry) stays one thread and sees every datum
in log-time order exactly as if it read the file itself; only where the work is done changes.
A reader thread pulls the recording's items (MCAP and image decoding) and, for a network
detector, runs the network on up to ``batch`` frames at a time, while the loop processes the
items before them. onnxruntime and the image decoder release the GIL, so on two cores the
network's time (most of a replay's) and the loop's overlap instead of adding up.

The loop's detector is :class:`LookaheadDetector`: for a frame computed ahead, its boxes (the
network's own, converted and counted as the flight's detector does); for any other image, the
network itself. A batch whose network run raised is not computed ahead: the loop's call then
runs that frame alone, and the runner counts its error as it would without the look-ahead.
A recording that breaks off (a :class:`BagError`) raises in the loop after every item read
before it, as the file itself would.

Why here and not in the runner: the flight's camera hands one frame at a time, live; only a
recording knows the frames to come.
"""

from __future__ import annotations

import queue
import threading
from collections import OrderedDict
from collections.abc import Iterator
from typing import Any

import numpy as np

from insulator_rs.ports.detector import Detections, NetworkDetector
from insulator_rs.recording.reader import Item

BATCH_FRAMES = 4  # frames a network run takes when that many are ready (issue 23: >= 4)
CHUNK_ITEMS = 256  # items handed over at once when frames are sparse (scans and poses only)
DEPTH_CHUNKS = 4  # chunks read ahead at most (memory: ~ DEPTH_CHUNKS * BATCH_FRAMES decoded frames)
_PUT_WAIT_S = 0.1  # how often a blocked reader checks whether the replay stopped


class _End:
    """The reader's last word: the recording ended (``error`` None) or broke off."""

    def __init__(self, error: BaseException | None) -> None:
        self.error = error


class Lookahead:
    """The recording's items read (and their frames detected) ahead; see the module docstring.

    ``items``: the recording's item iterator (read only by the thread); ``network``: the
    replay's detector when it is a network (None: decoding ahead only, e.g. a replay that
    detects every ``detect_period`` s, where most frames are never asked for)."""

    def __init__(self, items: Iterator[Item], network: NetworkDetector | None, *, batch: int = BATCH_FRAMES,
                 depth: int = DEPTH_CHUNKS) -> None:
        if batch < 1:
            raise ValueError(f"batch: must be >= 1, got {batch}")
        if depth < 1:
            raise ValueError(f"depth: must be >= 1, got {depth}")
        self._items = items
        self.network = network
        self.batch = batch
        self._queue: queue.Queue[list[Item] | _End] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        # id(image) -> (image, its detections), in frame order; the image is held so that its id
        # cannot be reused while the entry lives
        self._ahead: OrderedDict[int, tuple[np.ndarray, Detections]] = OrderedDict()
        self.counts = {"frames_ahead": 0, "network_runs": 0, "batches_failed": 0}
        self._thread = threading.Thread(target=self._read, name="replay-lookahead", daemon=True)
        self._started = False

    # -- the loop's side -------------------------------------------------------------------
    def items(self) -> Iterator[Item]:
        """The recording's items in their order; its BagError at the point it broke off."""
        if not self._started:
            self._started = True
            self._thread.start()
        try:
            while True:
                got = self._queue.get()
                if isinstance(got, _End):
                    if got.error is not None:
                        raise got.error
                    return
                yield from got
        finally:
            self.close()

    def detector(self) -> LookaheadDetector | None:
        """The loop's detector (None without a network: the replay keeps its own)."""
        return None if self.network is None else LookaheadDetector(self)

    def take(self, image: np.ndarray) -> Detections | None:
        """The detections computed ahead for ``image`` (None: not computed ahead). Entries of
        frames before it were passed over (a replay that skipped them) and are dropped."""
        with self._lock:
            entry = self._ahead.get(id(image))
            if entry is None or entry[0] is not image:
                return None
            while True:
                key, (_, detections) = self._ahead.popitem(last=False)
                if key == id(image):
                    return detections

    def close(self) -> None:
        """Stop reading ahead (the replay ended or was interrupted)."""
        self._stop.set()
        with self._lock:
            self._ahead.clear()

    # -- the reader thread -----------------------------------------------------------------
    def _read(self) -> None:
        chunk: list[Item] = []
        frames: list[np.ndarray] = []
        try:
            for item in self._items:
                chunk.append(item)
                if item.kind == "frame" and self.network is not None:
                    frames.append(item.value.image)
                if len(frames) >= self.batch or len(chunk) >= CHUNK_ITEMS:
                    self._detect(frames)
                    if not self._put(chunk):
                        return
                    chunk, frames = [], []
            self._detect(frames)
            if self._put(chunk):
                self._put(_End(None))
        except BaseException as exc:  # noqa: BLE001 - handed to the loop, raised there
            self._detect(frames)
            if self._put(chunk):
                self._put(_End(exc))

    def _detect(self, frames: list[np.ndarray]) -> None:
        if not frames or self.network is None or self._stop.is_set():
            return
        try:
            found = self.network.detect_batch(frames)
        except Exception:  # noqa: BLE001 - the loop's own call meets (and counts) the error
            self.counts["batches_failed"] += 1
            return
        self.counts["network_runs"] += 1
        with self._lock:
            for image, detections in zip(frames, found):
                self._ahead[id(image)] = (image, detections)
        self.counts["frames_ahead"] += len(frames)

    def _put(self, got: list[Item] | _End) -> bool:
        """Hand ``got`` to the loop; False once the loop stopped (the reader then ends)."""
        if isinstance(got, list) and not got:
            return not self._stop.is_set()
        while not self._stop.is_set():
            try:
                self._queue.put(got, timeout=_PUT_WAIT_S)
                return True
            except queue.Full:
                continue
        return False


class LookaheadDetector:
    """The replay's detector port over a :class:`Lookahead`: the boxes computed ahead for a
    frame, else the network on it (see the module docstring). Named as the network is."""

    def __init__(self, lookahead: Lookahead) -> None:
        assert lookahead.network is not None
        self.lookahead = lookahead
        self.network: NetworkDetector = lookahead.network
        self.name = self.network.name

    @property
    def dropped(self) -> Any:
        return self.network.dropped

    def __call__(self, image: np.ndarray) -> np.ndarray:
        detections = self.lookahead.take(image)
        if detections is None:
            return self.network(image)
        return self.network.boxes(detections)
