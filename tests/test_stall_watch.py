"""The companion's stall watch (flight/stall_watch.py): an interpreter held by one thread is
counted with its length, and the stacks written during the stall name the code that held it.

Reference: the stall is made here, by a known function holding the GIL for a known time
(``sys.setswitchinterval`` raised so that no other Python thread runs meanwhile, as a long C call
does)."""

from __future__ import annotations

import sys
import time

import pytest

from insulator_rs.flight.stall_watch import StallWatch

HELD_S = 1.2


def _hold_the_interpreter(seconds: float) -> None:
    old = sys.getswitchinterval()
    sys.setswitchinterval(10.0)  # no other thread gets the GIL until this returns
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            pass
    finally:
        sys.setswitchinterval(old)


def test_a_held_interpreter_is_counted_and_its_stack_written(tmp_path):
    stacks = tmp_path / "stacks.txt"
    watch = StallWatch(dump=stacks).start()
    try:
        time.sleep(0.2)
        _hold_the_interpreter(HELD_S)
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
    assert "_hold_the_interpreter" in text, text


def test_without_a_file_it_counts_and_writes_nothing(tmp_path):
    watch = StallWatch().start()
    try:
        _hold_the_interpreter(HELD_S)
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
