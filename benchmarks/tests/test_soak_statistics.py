"""The soak's test of a route's p99 growth: a later window counts as more than 20 % slower only beyond chance."""
from __future__ import annotations

import numpy as np

from benchmarks.soak import p99_ratio_lower_bound


def test_a_window_whose_answers_all_take_twice_as_long_is_bounded_near_two():
    first = list(np.random.default_rng(1).uniform(0.005, 0.010, 600))
    assert 1.8 < p99_ratio_lower_bound(first, [2 * v for v in first]) <= 2.0


def test_one_slow_answer_among_twenty_is_not_growth():
    first = [0.005 + 0.0001 * i for i in range(20)]
    later = first[:-1] + [3 * first[-1]]  # its p99 is nearly three times the first window's
    assert np.percentile(later, 99) / np.percentile(first, 99) > 2.5
    assert p99_ratio_lower_bound(first, later) < 1.2


def test_the_same_answers_again_are_not_growth():
    first = list(np.random.default_rng(2).gamma(2.0, 0.004, 300))
    assert p99_ratio_lower_bound(first, list(first)) < 1.0


def test_a_process_own_memory_leaves_out_the_shared_memory_it_has_touched():
    import mmap
    import os

    from benchmarks.soak import own_mb, process_sample

    assert own_mb({"rss_mb": 30.0, "shared_mb": 12.0}) == 18.0
    assert own_mb({"rss_mb": 30.0}) == 30.0  # a sample from before the soak read shared memory
    if not os.path.exists("/proc/self/status"):
        return
    before = process_sample(os.getpid())
    shared = mmap.mmap(-1, 64 << 20, flags=mmap.MAP_SHARED)  # as PostgreSQL's buffer pool or Ray's object store
    shared.write(b"x" * (64 << 20))  # every page touched
    after = process_sample(os.getpid())
    shared.close()
    assert after["shared_mb"] - before["shared_mb"] > 60
    assert after["rss_mb"] - before["rss_mb"] > 60
    assert abs(own_mb(after) - own_mb(before)) < 20
