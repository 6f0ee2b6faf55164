"""Run the tasks of a study: in this process (one worker), on the local cores (processes) or on a
Dask cluster (striptri.parallel.map_unordered). Every task carries its own seed, so the results do
not depend on what runs them; they come back sorted by task key."""

from __future__ import annotations

import os
from collections.abc import Callable

from striptri.parallel import map_unordered
from striptri.study.options import Task
from striptri.study.trial import run_task

Progress = Callable[[int, int], None]  # (done, total)


def run_tasks(tasks: list[Task], workers: int | None = None, scheduler=None,
              progress: Progress | None = None, run: Callable = run_task) -> list[tuple[Task, list[dict], dict]]:
    """-> [(task, rows, along)] sorted by task key. scheduler: None (local), a Dask scheduler
    address ("tcp://host:8786") or a dask.distributed.Client. workers: local processes
    (None: os.cpu_count(); 1: in this process). run: the function of one task (a module-level
    function: it travels to the workers), run_task or study.project.run_project_task."""
    if scheduler is None:
        workers = os.cpu_count() or 1 if workers is None else int(workers)
        if workers < 1:
            raise ValueError("workers must be >= 1")
    out = []
    for done, (i, result) in enumerate(map_unordered(run, tasks, workers, scheduler), start=1):
        out.append((tasks[i], *result))
        if progress is not None:
            progress(done, len(tasks))
    return sorted(out, key=lambda item: item[0].key)
