"""The report's figures drawn by a second process while the run goes on (issue 29).

matplotlib is pure Python: its import (0.4-0.5 s) and the drawing of the report's figures (0.4-0.7
s) hold the interpreter, so a thread cannot take them to the second core. A process can. The
pipeline starts one (:func:`worker_for`) when the run is large enough to use both cores
(:func:`when_to_start`; ``--threads 1`` or STRIPTRI_THREADS=1: none), with the run or, for a large
one, once its peaks of memory are behind: ``python -m
striptri.report.drawing``, a fresh interpreter (not a fork of a process with threads, nor
multiprocessing's spawn, which would run a caller's unguarded script again) that imports matplotlib
on the other core, waits, and draws the figures it is sent. The command's process never imports
matplotlib then.

The report asks for a figure with :func:`draw` (a figure function of report.figures or
report.plan_views and its arguments: arrays and small records). Without a worker the figure is
drawn at once and its PNG bytes returned; with one, the call is queued (without waiting) and a
:class:`Pending` figure returned, which :func:`html_of` writes as a placeholder that :func:`fill`
replaces by the image when the report is complete, waiting for the drawings only then. The same
function draws the same pixels in either process: the report's images are the same byte for byte
(tested).

Failure is not a result, and neither is a lost figure: a figure that fails in the worker, or a
worker that dies, cannot start or does not answer within WAIT_SECONDS, is drawn again in this
process, which raises what it raises there. The worker runs in a session of its own (a Ctrl-C at the
terminal reaches the command only, which ends the worker), ends when its input ends (also when the
command dies), writes no file, and is killed when the command is done with it.
"""

from __future__ import annotations

import contextlib
import importlib
import itertools
import os
import pickle
import queue
import signal
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

# the figures' numpy work is small: no BLAS threads beside the command's
WORKER_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
WAIT_SECONDS = 600.0  # the longest wait for one drawing (the 100,000-photo block's take seconds); then drawn here
MARK = "\ue000"  # a private-use character around a placeholder: never in the report's own text


@dataclass(frozen=True)
class Pending:
    """A figure queued to the worker: its key, and the call to draw it here should the worker fail."""

    key: int
    function: object
    args: tuple
    kwargs: dict = field(default_factory=dict)

    @property
    def placeholder(self) -> str:
        return f"{MARK}figure {self.key}{MARK}"


class Worker:
    """One drawing process (``python -m striptri.report.drawing``): jobs in through its standard
    input, PNG bytes out through its standard output, each a length-prefixed pickle. A thread sends
    the jobs and one receives the drawings, so that neither side waits for the other's pipe."""

    def __init__(self):
        # the striptri this process runs, wherever it was imported from
        home = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        path = os.pathsep.join(p for p in (home, os.environ.get("PYTHONPATH", "")) if p)
        self.process = subprocess.Popen(
            [sys.executable, "-m", __name__], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL, env=dict(os.environ, **WORKER_ENVIRONMENT, PYTHONPATH=path),
            start_new_session=True)  # not in the terminal's process group: the command takes Ctrl-C
        self.keys = itertools.count()
        self.outbox: queue.SimpleQueue = queue.SimpleQueue()
        self.done: dict[int, tuple[bool, bytes | None]] = {}
        self.arrived = threading.Condition()
        self.alive = True
        self.placed: dict[int, tuple[Pending, object]] = {}  # html_of's placeholders: key -> (figure, markup)
        self.threads = [threading.Thread(target=self._send, name="striptri-figures-out", daemon=True),
                        threading.Thread(target=self._receive, name="striptri-figures-in", daemon=True)]
        for thread in self.threads:
            thread.start()

    def submit(self, function, args: tuple, kwargs: dict) -> Pending:
        job = Pending(next(self.keys), function, args, kwargs)
        try:
            message = pickle.dumps((job.key, function.__module__, function.__qualname__, args, kwargs),
                                   protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # arguments that do not pickle: drawn here when filled in
            with self.arrived:
                self.done[job.key] = (False, None)
            return job
        self.outbox.put(message)
        return job

    def png(self, job: Pending) -> bytes:
        """The figure's PNG bytes: the worker's, or drawn here when the worker failed on it, has
        ended, or has not answered within WAIT_SECONDS (then it is killed: a hung worker must not
        hang the command)."""
        deadline = time.monotonic() + WAIT_SECONDS
        with self.arrived:
            while job.key not in self.done and self.alive:
                if not self.arrived.wait(timeout=1.0) and self.process.poll() is not None:
                    self.alive = False  # ended without a word (its output's end is on its way)
                elif time.monotonic() > deadline:
                    self.process.kill()
                    self.alive = False
            ok, png = self.done.pop(job.key, (False, None))
        return png if ok else _call(job.function, job.args, job.kwargs)

    def stop(self) -> None:
        """End the worker. It holds nothing of the run (it writes no file; a figure asked of it and
        not yet answered is drawn here), so it is killed at once: left to unwind an interpreter with
        matplotlib loaded, it kept the command waiting 0.15 s at its end."""
        self.outbox.put(None)  # the sender's end, should the kill not reach the worker
        try:
            self.process.kill()
            self.process.wait()
        finally:
            for stream in (self.process.stdin, self.process.stdout):
                with contextlib.suppress(OSError):
                    stream.close()

    def _send(self) -> None:
        try:
            while (message := self.outbox.get()) is not None:
                _write(self.process.stdin, message)
            self.process.stdin.close()
        except (OSError, ValueError):  # the worker has gone: its figures are drawn here
            self._lost()

    def _receive(self) -> None:
        try:
            while (message := _read(self.process.stdout)) is not None:
                key, ok, png = pickle.loads(message)
                with self.arrived:
                    self.done[key] = (ok, png)
                    self.arrived.notify_all()
        except (OSError, ValueError, EOFError, pickle.UnpicklingError):
            pass
        self._lost()

    def _lost(self) -> None:
        with self.arrived:
            self.alive = False
            self.arrived.notify_all()


def _write(stream, message: bytes) -> None:
    stream.write(struct.pack(">Q", len(message)))
    stream.write(message)
    stream.flush()


def _read(stream) -> bytes | None:
    """One message, or None at the end of the stream."""
    head = stream.read(8)
    if len(head) < 8:
        return None
    size = struct.unpack(">Q", head)[0]
    message = stream.read(size)
    if len(message) < size:
        return None
    return message


_current: list[Worker] = []  # the worker of the running pipeline, innermost last


@contextlib.contextmanager
def worker_for(use: bool):
    """A drawing worker for the block when ``use`` (the pipeline's decision: :func:`when_to_start`) and one
    can be started; the figures of :func:`draw` go to it. Stopped at the end of the block, whatever
    ends it."""
    worker = None
    if use:
        try:
            worker = Worker()
        except Exception:  # no process can be started here (a sandbox, no semaphores): draw in this one
            worker = None
    if worker is not None:
        _current.append(worker)
    try:
        yield worker
    finally:
        if worker is not None:
            _current.remove(worker)
            worker.stop()


# From this many plate measurements on, the worker starts after the gross-error tests: the run's own
# peaks of memory (the iterations, the tests) are behind, and the point precision and the tables
# take long enough for its import. Below, it starts with the run: the worker's 65-100 MB beside a
# small run's memory, and no phase after the tests long enough to hide its import.
LATER_FROM = 50_000


def when_to_start(rays_per_point) -> str | None:
    """When a run with these rays per point (n_points,) starts its drawing worker: "now" (with
    the run), "later" (after the gross-error tests: LATER_FROM measurements or more), or None: no
    worker, when the run is too small to use more than one thread (solvers.threads.chunk_threads on
    its ray pairs, the sum of k^2 over its points of k rays; at least two cores, not ``--threads
    1``): a smaller run ends before the worker would have imported matplotlib."""
    from ..solvers.threads import chunk_threads

    import numpy as np

    k = np.asarray(rays_per_point, dtype=np.int64)
    if chunk_threads(int(k @ k)) < 2:
        return None
    return "later" if int(k.sum()) >= LATER_FROM else "now"


def draw(function, *args, **kwargs):
    """The figure ``function(*args, **kwargs)`` (PNG bytes): queued to the running worker (a
    Pending), else drawn now (bytes)."""
    if _current:
        return _current[-1].submit(function, args, kwargs)
    return function(*args, **kwargs)


def drawing_elsewhere() -> bool:
    """Whether a worker draws the figures of :func:`draw` now."""
    return bool(_current)


def html_of(figure, markup) -> str:
    """The HTML of a figure of :func:`draw`: ``markup(png)`` for its PNG bytes, or for a Pending one
    a placeholder that :func:`fill` replaces by that markup."""
    if isinstance(figure, Pending) and _current:
        _current[-1].placed[figure.key] = (figure, markup)
        return figure.placeholder
    if isinstance(figure, Pending):  # its worker has ended: drawn here
        figure = _call(figure.function, figure.args, figure.kwargs)
    return markup(figure)


def fill(text: str) -> str:
    """``text`` with the placeholders of the running worker's figures replaced by their markup,
    waiting for the drawings (in the order they were asked for)."""
    if not _current:
        return text
    worker = _current[-1]
    for key in sorted(worker.placed):
        job, markup = worker.placed.pop(key)
        text = text.replace(job.placeholder, markup(worker.png(job)), 1)
    return text


def _call(function, args: tuple, kwargs: dict) -> bytes:
    return function(*args, **kwargs)


def _serve(jobs, results) -> None:  # pragma: no cover - runs in the worker process
    """The worker: import what the figures need, then draw every job until its input ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is the command's to handle
    from .figures import import_figure_modules

    import_figure_modules()
    while (message := _read(jobs)) is not None:
        key, module, name, args, kwargs = pickle.loads(message)
        try:
            function = importlib.import_module(module)
            for part in name.split("."):
                function = getattr(function, part)
            answer = (key, True, function(*args, **kwargs))
        except Exception:  # drawn again by the command, which raises it there
            answer = (key, False, None)
        _write(results, pickle.dumps(answer, protocol=pickle.HIGHEST_PROTOCOL))


if __name__ == "__main__":  # pragma: no cover - the worker process
    # the drawings go out on the standard output as it was; anything printed goes to the standard error
    answers = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    _serve(sys.stdin.buffer, answers)
