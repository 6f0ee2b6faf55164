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
