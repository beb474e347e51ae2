"""Exact sample accounting from sequence numbers (daq/sequence.py): drops, duplicates, wraps,
restarts, the missing tail, and a file's counts read back through ``ambdaq info``."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ambdaq.acquisition.sequence import SequenceTracker, WRAP

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


def judge(seq, times, tracker=None):
    tracker = tracker or SequenceTracker()
    v = tracker.admit(np.array(seq, dtype=np.uint32), np.array(times, dtype=np.int64))
    return tracker, v, v.counts("dev", slice(0, len(seq)), np.array(seq, dtype=np.uint32), np.array(times))


def test_a_repeated_sample_is_a_duplicate_not_a_wrap():
    """Issue 12's file: seq 1317 1318 1318 1319 ... 1557 1559 counted 2**32 drops."""
    _, v, c = judge([1317, 1318, 1318, 1319, 1557, 1559], [0, 1, 1, 2, 240, 242])
    assert list(v.keep) == [True, True, False, True, True, True]
    assert (c.samples, c.drops, c.duplicates, c.wraps, c.restarts) == (5, 237 + 1, 1, 0, 0)


def test_wrap_and_restart_and_late_copy():
    _, v, c = judge([WRAP - 2, WRAP - 1, 0, 2], [0, 1, 2, 4])
    assert (c.samples, c.drops, c.wraps) == (4, 1, 1)
    tracker, v, c = judge([100, 101, 5, 6], [10, 11, 12, 13])  # the device restarted at 5, time went on
    assert list(v.keep) == [True] * 4 and (c.drops, c.restarts, c.duplicates) == (0, 1, 0)
    _, v, c = judge([3], [9], tracker)  # behind, not after the last time: a late copy
    assert list(v.keep) == [False] and c.duplicates == 1


def test_the_tail_a_device_never_sent_is_counted():
    tracker, _, c = judge([7, 8, 10], [0, 1, 3])
    assert c.drops == 1 and tracker.missing_after(10) == 6  # periods 7..16 were due: 11..16 never came
    assert tracker.missing_after(4) == 0


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(st.integers(1, 50).map(lambda k: ("step", k)), st.just(("repeat", 0))), max_size=60),
       st.integers(0, WRAP - 1))
def test_counts_are_exact_for_any_mix_of_gaps_repeats_and_wraps(ops, start):
    """Build a stream from known events and check every count against what was built, whether
    it arrives in one block or in pieces."""
    seq, times, lost, dups = [start], [0], 0, 0
    for op, k in ops:
        if op == "step":
            seq.append((seq[-1] + k) % WRAP)
            times.append(times[-1] + k)
            lost += k - 1
        else:
            seq.append(seq[-1])
            times.append(times[-1])
            dups += 1
    wraps = sum(1 for a, b, (op, _k) in zip(seq, seq[1:], ops) if op == "step" and b < a)
    for cut in (len(seq), max(1, len(seq) // 3)):
        tracker = SequenceTracker()
        total = [0, 0, 0, 0]
        for i in range(0, len(seq), cut):
            _, _, c = judge(seq[i:i + cut], times[i:i + cut], tracker)
            total = [a + b for a, b in zip(total, (c.samples, c.drops, c.duplicates, c.wraps))]
        assert total == [len(seq) - dups, lost, dups, wraps]
