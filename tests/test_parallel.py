"""striptri.parallel.map_unordered: every task once, with its index, in this process or in local
processes; a task's exception reaches the caller."""

from __future__ import annotations

import pytest

from striptri.parallel import map_unordered


def _square(x: int) -> int:
    if x < 0:
        raise ValueError(f"negative: {x}")
    return x * x


@pytest.mark.parametrize("workers", [1, 2])
def test_every_task_comes_back_once_with_its_index(workers):
    tasks = list(range(7))
    got = dict(map_unordered(_square, tasks, workers))
    assert got == {i: i * i for i in tasks}


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_task_raises_in_the_caller(workers):
    with pytest.raises(ValueError, match="negative: -3"):
        list(map_unordered(_square, [1, 2, -3, 4], workers))


def test_workers_must_be_positive():
    with pytest.raises(ValueError):
        list(map_unordered(_square, [1, 2], 0))


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_run_all_runs_every_item_keeps_the_error_state_and_raises_the_first_failure(threads):
    """parallel.run_all: every item runs (also after a failure), in the caller's numpy error state,
    and the failure of the first failing item in the items' order is raised."""
    import threading

    import numpy as np

    from striptri.parallel import run_all

    done, lock = [], threading.Lock()

    def work(i):
        with lock:
            done.append(i)
        if i in (2, 4):
            raise ValueError(f"item {i}")
        np.float64(1.0) / np.float64(0.0)  # raises under errstate(divide="raise")

    with np.errstate(divide="ignore"):
        with pytest.raises(ValueError, match="item 2"):
            run_all(work, list(range(6)), threads)
    assert sorted(done) == list(range(6)) if threads > 1 else done == [0, 1, 2]
    with np.errstate(divide="raise"):
        with pytest.raises(FloatingPointError):
            run_all(work, [0, 1], threads)
