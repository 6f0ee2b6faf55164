"""The statistics of bench_pairs.py's table: the sign test's interval for the median ratio and its
one-sided p-value for "below 1.0", against their definitions worked out by enumeration."""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "bench"))
import bench_pairs  # noqa: E402


def _coverage_by_enumeration(n: int, k: int) -> float:
    """P(x_(k) <= median <= x_(n+1-k)) for n draws of a continuous distribution: each draw falls
    below the median with probability 1/2, independently; the interval misses it when fewer than k
    fall below or fewer than k above (all 2^n outcomes counted)."""
    hits = sum(k <= sum(signs) <= n - k for signs in itertools.product((0, 1), repeat=n))
    return hits / 2**n


@pytest.mark.parametrize("n", range(1, 15))
def test_interval_is_the_widest_order_statistics_pair_with_95_percent(n):
    values = list(np.random.default_rng(n).normal(size=n))
    low, high, coverage = bench_pairs.median_interval(values)
    x = sorted(values)
    k = x.index(low) + 1
    assert high == x[n - k]
    assert coverage == pytest.approx(_coverage_by_enumeration(n, k))
    if k > 1:  # the largest k that still covers 95 %: one more misses it
        assert coverage >= 0.95 and (k + 1 > (n + 1) // 2 or _coverage_by_enumeration(n, k + 1) < 0.95)
    else:  # too few pairs: the extremes, with what they cover
        assert (low, high) == (x[0], x[-1]) and (n < 6 or _coverage_by_enumeration(n, 2) < 0.95)


def test_interval_of_the_tables():
    """The usual table of the sign test's 95 % interval: the 2nd and 8th of 9, the 6th and 15th of 20."""
    assert bench_pairs.median_interval(range(1, 10))[:2] == (2, 8)
    assert bench_pairs.median_interval(range(1, 21))[:2] == (6, 15)


@pytest.mark.parametrize("below, n", [(7, 9), (9, 9), (0, 5), (12, 18), (5, 6)])
def test_sign_test_p_value_is_the_binomial_tail(below, n):
    values = [0.9] * below + [1.1] * (n - below)
    got_below, p = bench_pairs.sign_test_below(values)
    tail = sum(sum(s) >= below for s in itertools.product((0, 1), repeat=n)) / 2**n
    assert got_below == below and p == pytest.approx(tail)


def test_sign_test_leaves_out_ties_with_the_limit():
    below, p = bench_pairs.sign_test_below([0.9, 0.9, 1.0, 1.0, 1.2])
    assert below == 2 and p == pytest.approx(sum(sum(s) >= 2 for s in itertools.product((0, 1), repeat=3)) / 8)


def test_the_peers_seconds_are_its_last_lines():
    """peer_seconds reads colmap_worker.py's last line of output (its JSON record), nan without one."""
    record = '{"seconds": 4.25, "iterations": 13}'
    assert bench_pairs.peer_seconds({"stdout": "Ceres says something\n" + record + "\n"}) == 4.25
    assert np.isnan(bench_pairs.peer_seconds({"stdout": ""}))
    assert np.isnan(bench_pairs.peer_seconds({}))
