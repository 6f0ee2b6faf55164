"""Run the tasks of a study: in this process (one worker), on the local cores
(concurrent.futures.ProcessPoolExecutor) or on a Dask cluster (dask.distributed, optional extra
``striptri[dask]``, imported only when asked for). Every task carries its own seed, so the results do
not depend on what runs them; they come back sorted by task key."""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed

from striptri.errors import InputError
from striptri.study.options import Task
from striptri.study.trial import run_task

Progress = Callable[[int, int], None]  # (done, total)


def run_tasks(tasks: list[Task], workers: int | None = None, scheduler=None,
              progress: Progress | None = None, run: Callable = run_task) -> list[tuple[Task, list[dict], dict]]:
    """-> [(task, rows, along)] sorted by task key. scheduler: None (local), a Dask scheduler
    address ("tcp://host:8786") or a dask.distributed.Client. workers: local processes
    (None: os.cpu_count(); 1: in this process). run: the function of one task (a module-level
    function: it travels to the workers), run_task or study.project.run_project_task."""
    if scheduler is not None:
        out = _run_dask(tasks, scheduler, progress, run)
    else:
        workers = os.cpu_count() or 1 if workers is None else int(workers)
        if workers < 1:
            raise ValueError("workers must be >= 1")
        out = _run_serial(tasks, progress, run) if workers == 1 or len(tasks) <= 1 else \
            _run_pool(tasks, workers, progress, run)
    return sorted(out, key=lambda item: item[0].key)


def _tick(progress, done, total):
    if progress is not None:
        progress(done, total)


def _run_serial(tasks, progress, run=run_task):
    out = []
    for i, task in enumerate(tasks):
        out.append((task, *run(task)))
        _tick(progress, i + 1, len(tasks))
    return out


def _run_pool(tasks, workers, progress, run=run_task):
    out = []
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks))) as pool:
        futures = {pool.submit(run, task): task for task in tasks}
        for i, future in enumerate(as_completed(futures)):
            out.append((futures[future], *future.result()))
            _tick(progress, i + 1, len(tasks))
    return out


def _run_dask(tasks, scheduler, progress, run=run_task):
    try:
        from dask.distributed import Client, as_completed as dask_completed
    except ImportError as exc:
        raise InputError("--scheduler", None, "a Dask cluster needs dask.distributed: "
                         "pip install 'striptri[dask]' (or 'dask[distributed]')") from exc
    own = not isinstance(scheduler, Client)
    client = Client(scheduler) if own else scheduler
    try:
        futures = client.map(run, tasks, pure=False)
        index = {f.key: t for f, t in zip(futures, tasks)}
        out = []
        for i, future in enumerate(dask_completed(futures)):
            out.append((index[future.key], *future.result()))
            _tick(progress, i + 1, len(tasks))
        return out
    finally:
        if own:
            client.close()
