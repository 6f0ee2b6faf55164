"""Independent tasks on the local cores or a Dask cluster, for studies (striptri.study.runner) and
the matcher (striptri.match.stages); and chunks of one adjustment on threads (:func:`map_ordered`).

:func:`map_unordered` runs ``fn(task)`` for every task: in this process (one worker), in local
processes (concurrent.futures.ProcessPoolExecutor, one per core by default) or on a Dask cluster
(dask.distributed, the optional extra ``striptri[dask]``, imported only when a scheduler is
given). ``fn`` must be a module-level function (it travels to the workers). Each worker process
keeps its BLAS to one thread (threadpoolctl): the processes already fill the cores, and BLAS
threads on top of them only contend.
"""

from __future__ import annotations

import collections
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed

import numpy as np

from striptri.errors import InputError


# chunks in flight per thread of map_ordered (measured, issue 29: the close-range block's sweeps of
# 59 chunks of very unequal work and the 5,000-photo block's 37 chunks ran 10-20 % faster with two
# than with one; the memory of two more chunks' results, 3-5 MB at 5,000 photos)
AHEAD_PER_THREAD = 2


def map_ordered(fn: Callable, items: Iterable, threads: int) -> Iterator:
    """fn(item) for every item, in the items' order, computed by ``threads`` threads ahead of the
    caller (solvers.threads.chunk_threads): the chunks of an adjustment, whose numpy work (batched
    products, factorisations of small matrices, elementwise arithmetic on large arrays) releases
    the GIL. AHEAD_PER_THREAD chunks per thread are in the works while the caller takes the one
    before, so memory holds 2 x threads + 1 chunks' results (a 4,096-group chunk's products are tens
    of MB): with one per thread, a thread whose chunk was done waited while the caller still
    waited for the one before it or summed it (docs/decisions.md "Two chunks per thread in flight").
    One thread (or one item): fn runs here, item by item. The caller's numpy error state holds in
    the threads too (np.errstate is per thread), and the first exception of a task is raised here."""
    items = list(items)
    if threads <= 1 or len(items) <= 1:  # no pool for one chunk (a small project)
        yield from map(fn, items)
        return
    state = np.geterr()

    def task(item):
        with np.errstate(**state):
            return fn(item)

    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="striptri-chunk") as pool:
        ahead = AHEAD_PER_THREAD * threads
        pending = collections.deque(pool.submit(task, item) for item in items[:ahead])
        items = iter(items[ahead:])
        try:
            while pending:
                result = pending.popleft().result()
                for item in items:  # one more in flight for the one taken
                    pending.append(pool.submit(task, item))
                    break
                yield result
        finally:  # the caller stopped early or a task failed: drop what has not started
            for future in pending:
                future.cancel()


def run_all(fn: Callable, items: Sequence, threads: int) -> None:
    """fn(item) for every item on ``threads`` threads, all submitted at once (a thread that finishes
    takes the next item: give the largest first), for work whose numpy and BLAS calls release the
    GIL (the selected inversion's independent subtrees). The caller's numpy error state holds in
    the threads, as in :func:`map_ordered`; the exception of the first failing item (in the items'
    order) is raised once all have ended. One thread (or one item): here, item by item."""
    if threads <= 1 or len(items) <= 1:
        for item in items:
            fn(item)
        return
    state = np.geterr()

    def task(item):
        with np.errstate(**state):
            fn(item)

    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="striptri-all") as pool:
        futures = [pool.submit(task, item) for item in items]
    for future in futures:
        if future.exception() is not None:
            raise future.exception()


def map_unordered(fn: Callable, tasks: Sequence, workers: int | None = None,
                  scheduler=None) -> Iterator[tuple[int, object]]:
    """(index of the task, fn(task)) for every task, in the order they finish. scheduler: None
    (local), a Dask scheduler address ("tcp://host:8786") or a dask.distributed.Client; workers:
    local processes (None: os.cpu_count(); 1: in this process). The first exception of a task is
    raised here."""
    if scheduler is not None:
        yield from _dask(fn, tasks, scheduler)
        return
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if workers < 1:
        raise ValueError("workers must be >= 1")
    if workers == 1 or len(tasks) <= 1:
        for i, task in enumerate(tasks):
            yield i, fn(task)
        return
    from concurrent.futures import ProcessPoolExecutor  # 40 ms of imports (multiprocessing): not for every command

    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), initializer=_one_blas_thread) as pool:
        futures = {pool.submit(fn, task): i for i, task in enumerate(tasks)}
        try:
            for future in as_completed(futures):
                yield futures[future], future.result()
        finally:
            for future in futures:
                future.cancel()


def _one_blas_thread() -> None:
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


def _dask(fn, tasks, scheduler):
    try:
        from dask.distributed import Client, as_completed as dask_completed
    except ImportError as exc:
        raise InputError("--scheduler", None, "a Dask cluster needs dask.distributed: "
                         "pip install 'striptri[dask]' (or 'dask[distributed]')") from exc
    own = not isinstance(scheduler, Client)
    client = Client(scheduler) if own else scheduler
    try:
        futures = client.map(fn, list(tasks), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for future in dask_completed(futures):
            yield index[future.key], future.result()
    finally:
        if own:
            client.close()
