"""The companion's stall watch (flight/stall_watch.py): an interpreter held by one thread is
counted with its length, and the stacks written during the stall name the code that held it.

Reference: the stall is made here, by a known function holding the GIL for a known time
(``sys.setswitchinterval`` raised so that no other Python thread runs meanwhile, as a long C call
does)."""

from __future__ import annotations

import gc
import sys
import time

import pytest
from helpers.interpreter_stall import hold_the_interpreter

from insulator_rs.flight.gc_pauses import GcPauseLog, startup_heap_frozen
from insulator_rs.flight.stall_watch import TICK_S, StallWatch

HELD_S = 1.2


def test_a_held_interpreter_is_counted_and_its_stack_written(tmp_path):
    stacks = tmp_path / "stacks.txt"
    watch = StallWatch(dump=stacks).start()
    try:
        time.sleep(0.2)
        hold_the_interpreter(HELD_S)
        time.sleep(0.2)
    finally:
        watch.stop()
    record = watch.record()
    assert record["count"] >= 1, record
    # the watch's timer may have fired up to one tick after the hold began; a loaded box only
    # lengthens what it measures
    assert record["max_s"] >= HELD_S - 0.2, record
    assert record["longest"][0]["length_s"] == record["max_s"]
    assert record["stacks"] == str(stacks)
    text = stacks.read_text()
    assert hold_the_interpreter.__name__ in text, text


def test_without_a_file_it_counts_and_writes_nothing(tmp_path):
    watch = StallWatch().start()
    try:
        hold_the_interpreter(HELD_S)
        time.sleep(0.2)
    finally:
        watch.stop()
    assert watch.record()["count"] >= 1
    assert watch.record()["stacks"] is None
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("threshold", [0.0, 0.05, -1.0, float("nan")])
def test_a_threshold_within_the_tick_is_refused_by_name(threshold):
    with pytest.raises(ValueError, match="threshold_s"):
        StallWatch(threshold_s=threshold)


# -- the collector's pauses (flight/gc_pauses.py) ---------------------------------------------
# Reference: collections made here by gc.collect(generation), whose count and generation the
# log must show, and gc.get_freeze_count() (CPython's own count of frozen objects).


def test_collections_are_timed_by_generation():
    log = GcPauseLog().start()
    try:
        for gen in (0, 1, 2):
            gc.collect(gen)
    finally:
        log.stop()
    record = log.record()
    gens = record["generations"]
    assert {"0", "1", "2"} <= set(gens), record
    assert all(gens[g]["count"] >= 1 and gens[g]["max_ms"] >= 0.0 for g in ("0", "1", "2"))
    assert record["longest"] and record["longest"][0]["length_ms"] == max(g["max_ms"] for g in gens.values())
    n = len(log.pauses)
    gc.collect()
    assert len(log.pauses) == n  # stopped: the callback is gone
    assert log._callback not in gc.callbacks


def test_the_startup_heap_is_frozen_for_the_flight_and_handed_back():
    assert gc.get_freeze_count() == 0
    kept = [[i] for i in range(1000)]  # tracked objects alive at "take-off"
    with startup_heap_frozen() as frozen:
        assert frozen >= len(kept) and gc.get_freeze_count() >= len(kept)
    assert gc.get_freeze_count() == 0
    del kept


def test_a_full_collection_walks_less_with_the_startup_heap_frozen():
    # CPython's gen-2 statistics count the objects a collection examined indirectly through its
    # time; the direct measure is that frozen objects are not in gc.get_objects(), which is what
    # a full collection walks.
    kept = [{"k": i} for i in range(20000)]
    walked_before = len(gc.get_objects())
    with startup_heap_frozen():
        walked_frozen = len(gc.get_objects())
    assert walked_frozen < walked_before - len(kept)
    del kept


def test_a_stall_says_how_much_of_it_was_the_collector(tmp_path):
    watch = StallWatch().start()
    garbage = []
    try:
        # a cycle-rich heap makes a long full collection; held past the threshold with the
        # interpreter's switching off, as a long collection holds the GIL
        for _ in range(300000):
            a: list = []
            a.append(a)
            garbage.append(a)
        old = sys.getswitchinterval()
        sys.setswitchinterval(10.0)
        try:
            t0 = time.monotonic()
            # the collection in the middle of the hold: a drop of the GIL the watch asked for
            # before the switching went off is served at the hold's start (one last wake-up
            # there); collecting at once let that wake-up fall after the collection
            while time.monotonic() - t0 < 0.3:
                pass
            del garbage
            gc.collect()
            while time.monotonic() - t0 < HELD_S:
                pass
        finally:
            sys.setswitchinterval(old)
        time.sleep(0.2)
    finally:
        watch.stop()
    record = watch.record()
    assert record["count"] >= 1, record
    assert record["gc"]["generations"]["2"]["count"] >= 1, record
    assert record["longest"][0]["gc_ms"] > 0.0, record
    assert record["longest"][0]["gc_ms"] <= record["longest"][0]["length_s"] * 1e3 + TICK_S * 1e3, record
