"""Read a recording ahead of the replay in threads: decoding, and the network's boxes for its
frames, run in batches on every core.

The replay's loop (clock, pairing, pipeline, registry) stays one thread and sees every datum
in log-time order exactly as if it read the file itself; only where the work is done changes.
A reader thread pulls the recording's items (MCAP and image decoding) in chunks of up to
``batch`` frames; ``workers`` network threads each run a chunk's frames through the network
in one batch (onnxruntime releases the GIL), while the loop processes the chunks before them,
in their order.

Why threads of one-threaded network runs: on the 2-core development box the network alone
takes 14.8 ms a frame on one thread and 8.1 on two (batches of 4), but beside the replay's loop
onnxruntime's two threads wait for each other at every operator while the loop holds one core,
and the replay ran barely faster than frame by frame (67.7x against 65x real time). Runs of one
thread each, as many as there are cores, keep every core busy whichever thread holds it.

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

import os
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
DEPTH_CHUNKS = 8  # chunks read ahead at most (memory: ~ DEPTH_CHUNKS * BATCH_FRAMES decoded frames)
_WAIT_S = 0.1  # how often a blocked thread checks whether the replay stopped


def default_workers() -> int:
    """Network threads: one a core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


class _Chunk:
    """Items read together, and whether their frames' network run is over (``done``)."""

    def __init__(self, items: list[Item], frames: list[np.ndarray]) -> None:
        self.items = items
        self.frames = frames
        self.detections: list[Detections] | None = None  # the network's, when its run succeeded
        self.done = threading.Event()
        if not frames:
            self.done.set()


class _End:
    """The reader's last word: the recording ended (``error`` None) or broke off."""

    def __init__(self, error: BaseException | None) -> None:
        self.error = error


class Lookahead:
    """The recording's items read (and their frames detected) ahead; see the module docstring.

    ``items``: the recording's item iterator (read only by the reader thread); ``network``: the
    replay's detector when it is a network (None: decoding ahead only, e.g. a replay that
    detects every ``detect_period`` s, where most frames are never asked for); ``workers``:
    network threads (default: one a core)."""

    def __init__(self, items: Iterator[Item], network: NetworkDetector | None, *, batch: int = BATCH_FRAMES,
                 depth: int = DEPTH_CHUNKS, workers: int | None = None) -> None:
        for name, value in (("batch", batch), ("depth", depth), ("workers", 1 if workers is None else workers)):
            if value < 1:
                raise ValueError(f"{name}: must be >= 1, got {value}")
        self._items = items
        self.network = network
        self.batch = batch
        self.workers = default_workers() if workers is None else workers
        self._ordered: queue.Queue[_Chunk | _End] = queue.Queue(maxsize=depth)
        self._work: queue.Queue[_Chunk] = queue.Queue()  # bounded by _ordered: a chunk enters both
        self._stop = threading.Event()
        self._lock = threading.Lock()
        # id(image) -> (image, its detections); the image is held so that its id cannot be
        # reused while the entry lives
        self._ahead: OrderedDict[int, tuple[np.ndarray, Detections]] = OrderedDict()
        self.counts = {"frames_ahead": 0, "network_runs": 0, "batches_failed": 0}
        self._threads = [threading.Thread(target=self._read, name="replay-lookahead", daemon=True)]
        if network is not None:
            self._threads += [threading.Thread(target=self._detect_chunks, name=f"replay-lookahead-network{k}",
                                               daemon=True) for k in range(self.workers)]
        self._started = False

    # -- the loop's side -------------------------------------------------------------------
    def items(self) -> Iterator[Item]:
        """The recording's items in their order; its BagError at the point it broke off."""
        if not self._started:
            self._started = True
            for thread in self._threads:
                thread.start()
        try:
            while True:
                got = self._ordered.get()
                if isinstance(got, _End):
                    if got.error is not None:
                        raise got.error
                    return
                got.done.wait()
                self._keep(got)
                yield from got.items
        finally:
            self.close()

    def _keep(self, chunk: _Chunk) -> None:
        """A chunk's detections, kept for :meth:`take` in frame order (workers finish out of order)."""
        if chunk.detections is None:
            return
        with self._lock:
            for image, detections in zip(chunk.frames, chunk.detections):
                self._ahead[id(image)] = (image, detections)

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
                    if not self._hand_on(_Chunk(chunk, frames)):
                        return
                    chunk, frames = [], []
            if self._hand_on(_Chunk(chunk, frames)):
                self._put(_End(None))
        except BaseException as exc:  # noqa: BLE001 - handed to the loop, raised there
            if self._hand_on(_Chunk(chunk, frames)):
                self._put(_End(exc))

    def _hand_on(self, chunk: _Chunk) -> bool:
        """Queue ``chunk`` in order and, with frames, for the network; False once the loop stopped."""
        if not chunk.items:
            return not self._stop.is_set()
        if not self._put(chunk):
            return False
        if not chunk.done.is_set():
            self._work.put(chunk)
        return True

    def _put(self, got: _Chunk | _End) -> bool:
        while not self._stop.is_set():
            try:
                self._ordered.put(got, timeout=_WAIT_S)
                return True
            except queue.Full:
                continue
        return False

    # -- the network threads ---------------------------------------------------------------
    def _detect_chunks(self) -> None:
        while not self._stop.is_set():
            try:
                chunk = self._work.get(timeout=_WAIT_S)
            except queue.Empty:
                continue
            try:
                chunk.detections = self._detect(chunk.frames)
            finally:
                chunk.done.set()

    def _detect(self, frames: list[np.ndarray]) -> list[Detections] | None:
        if self.network is None or self._stop.is_set():
            return None
        try:
            found = self.network.detect_batch(frames)
        except Exception:  # noqa: BLE001 - the loop's own call meets (and counts) the error
            with self._lock:
                self.counts["batches_failed"] += 1
            return None
        with self._lock:
            self.counts["network_runs"] += 1
            self.counts["frames_ahead"] += len(frames)
        return found


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
