"""The report's figures drawn by a second process while the run goes on (issue 29).

matplotlib is pure Python: its import (0.4-0.5 s) and the drawing of the report's figures (0.4-0.7
s) hold the interpreter, so a thread cannot take them to the second core. A process can. The
pipeline starts one (:func:`worker_for`) when the run is large enough to use both cores
(:func:`when_to_start`; ``--threads 1`` or STRIPTRI_THREADS=1: none), with the run or, for a large
one, once its peaks of memory are behind: ``python -m
striptri.report.drawing``, a fresh interpreter (not a fork of a process with threads, nor
multiprocessing's spawn, which would run a caller's unguarded script again) that imports matplotlib
on the other core, waits, and draws the figures it is sent. The command's process never imports
matplotlib then. For a small run (DRAWERS_NOW) the worker forks a twin once matplotlib is imported:
the figures of the tests, asked for together at the run's end, are drawn two at a time. The
``striptri adjust`` command starts that worker even before the project is read when the size of its
image_points.csv says the run will most likely take one (:func:`early_worker`); the pipeline takes
it or stops it.

The report asks for a figure with :func:`draw` (a figure function of report.figures or
report.plan_views and its arguments: arrays and small records). Without a worker the figure is
drawn at once and its PNG bytes returned; with one, the call is queued (without waiting) and a
:class:`Pending` figure returned, which :func:`html_of` writes as a placeholder that :func:`fill`
replaces by the image when the report is complete, waiting for the drawings only then. The same
function draws the same pixels in either process: the report's images are the same byte for byte
(tested).

Failure is not a result, and neither is a lost figure: a figure that fails in the worker, or a
worker that dies, cannot start or does not answer within WAIT_SECONDS, is drawn again in this
process, which raises what it raises there; the figures of a twin that never started, or has died,
go to the other drawer. The worker runs in a session of its own (a Ctrl-C at the terminal reaches
the command only, which ends the worker), ends when its input ends (also when the command dies),
writes no file, and is killed with its twin (its process group) when the command is done with it.
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
PARKED = "--parked"  # the worker's argument: wait for a byte on its input before importing matplotlib
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
    """The drawing processes: ``python -m striptri.report.drawing`` and, for ``drawers=2``, its
    twin, which it forks once matplotlib is imported (the import is paid once). Each drawer has a
    line: jobs in, PNG bytes out, each a length-prefixed pickle. A thread per line takes the next job
    from the common queue when its drawer is free, sends it and waits for the drawing, so that the
    figures go to whichever drawer is free and neither side waits for the other's pipe. A drawer
    first says it is ready (its pid): a line whose drawer never started takes no job."""

    def __init__(self, drawers: int = 1, parked: bool = False):
        """parked: the drawer waits, its interpreter started, before importing matplotlib, until
        :meth:`unpark` (its 15 MB instead of 65-100 MB meanwhile)."""
        # the striptri this process runs, wherever it was imported from
        home = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        path = os.pathsep.join(p for p in (home, os.environ.get("PYTHONPATH", "")) if p)
        twins = [(os.pipe(), os.pipe()) for _ in range(drawers - 1)]  # (jobs, answers) of each twin
        their_ends = [fd for jobs, answers in twins for fd in (jobs[0], answers[1])]
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-m", __name__, *([PARKED] if parked else []),
                 *(f"{jobs[0]},{answers[1]}" for jobs, answers in twins)],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, pass_fds=their_ends,
                env=dict(os.environ, **WORKER_ENVIRONMENT, PYTHONPATH=path),
                start_new_session=True)  # not in the terminal's process group: the command takes Ctrl-C
        except BaseException:
            for jobs, answers in twins:
                for fd in (*jobs, *answers):
                    os.close(fd)
            raise
        for fd in their_ends:
            os.close(fd)
        lines = [(self.process.stdin, self.process.stdout)]
        lines += [(os.fdopen(jobs[1], "wb"), os.fdopen(answers[0], "rb")) for jobs, answers in twins]
        self.parked = parked
        self.keys = itertools.count()
        self.outbox: queue.SimpleQueue = queue.SimpleQueue()  # (key, message) of the jobs not yet taken
        self.done: dict[int, tuple[bool, bytes | None]] = {}
        self.arrived = threading.Condition()
        self.lines_open = len(lines)
        self.alive = True  # some drawer may still draw
        self.pids: set[int] = set()  # the drawers that said they are ready
        self.placed: dict[int, tuple[Pending, object]] = {}  # html_of's placeholders: key -> (figure, markup)
        self.threads = [threading.Thread(target=self._line, args=line, name=f"striptri-figures-{i}", daemon=True)
                        for i, line in enumerate(lines)]
        for thread in self.threads:
            thread.start()

    def unpark(self) -> None:
        """Let a parked drawer import matplotlib and draw (it says it is ready only then, so no
        job reaches its input before this byte)."""
        if self.parked:
            self.parked = False
            with contextlib.suppress(OSError, ValueError):  # it has gone: its line ends, figures drawn here
                self.process.stdin.write(b"g")
                self.process.stdin.flush()

    def submit(self, function, args: tuple, kwargs: dict) -> Pending:
        job = Pending(next(self.keys), function, args, kwargs)
        try:
            message = pickle.dumps((job.key, function.__module__, function.__qualname__, args, kwargs),
                                   protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # arguments that do not pickle: drawn here when filled in
            with self.arrived:
                self.done[job.key] = (False, None)
            return job
        self.outbox.put((job.key, message))
        return job

    def png(self, job: Pending) -> bytes:
        """The figure's PNG bytes: the worker's, or drawn here when the worker failed on it, has
        ended, or has not answered within WAIT_SECONDS (then it is killed: a hung worker must not
        hang the command)."""
        deadline = time.monotonic() + WAIT_SECONDS
        with self.arrived:
            while job.key not in self.done and self.alive:
                if not self.arrived.wait(timeout=1.0) and self.process.poll() is not None and len(self.threads) == 1:
                    self.alive = False  # ended without a word (its output's end is on its way)
                elif time.monotonic() > deadline:
                    self._kill()
                    self.alive = False
            ok, png = self.done.pop(job.key, (False, None))
        return png if ok else _call(job.function, job.args, job.kwargs)

    def stop(self) -> None:
        """End the drawers. They hold nothing of the run (they write no file; a figure asked of them
        and not yet answered is drawn here), so they are killed at once: left to unwind an
        interpreter with matplotlib loaded, a drawer kept the command waiting 0.15 s at its end. A
        twin, the drawer's child, is reaped by the system."""
        for _ in self.threads:
            self.outbox.put(None)  # each line's end, should the kill not reach its drawer
        try:
            self._kill()
            self.process.wait()
        finally:
            for stream in (self.process.stdin, self.process.stdout):
                with contextlib.suppress(OSError):
                    stream.close()

    def _kill(self) -> None:
        """Kill the drawer and its twin (its process group: the drawer leads a session of its own)."""
        try:
            os.killpg(self.process.pid, signal.SIGKILL)
        except OSError:  # already ended (and reaped)
            with contextlib.suppress(OSError):
                self.process.kill()

    def _line(self, jobs, answers) -> None:
        """One drawer's line: wait until it is ready, then send it a job when it is free."""
        key = None
        try:
            ready = _read(answers)
            if ready is None:
                return
            with self.arrived:
                self.pids.add(pickle.loads(ready))
            while (item := self.outbox.get()) is not None:
                key, message = item
                try:
                    _write(jobs, message)
                except (OSError, ValueError):  # the drawer has gone before it took the job: another takes it
                    self.outbox.put(item)
                    key = None
                    return
                answer = _read(answers)
                if answer is None:
                    return
                key, ok, png = pickle.loads(answer)
                with self.arrived:
                    self.done[key] = (ok, png)
                    self.arrived.notify_all()
                key = None
        except (OSError, ValueError, EOFError, pickle.UnpicklingError):
            pass
        finally:
            for stream in (jobs, answers):  # (the worker's own are closed by stop too)
                with contextlib.suppress(OSError):
                    stream.close()
            with self.arrived:
                if key is not None:  # the drawer died on this job: drawn here (which raises what it raises)
                    self.done.setdefault(key, (False, None))
                self.lines_open -= 1
                self.alive = self.lines_open > 0
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
_early: list[Worker] = []  # the worker started by early_worker, until the pipeline takes or stops it


@contextlib.contextmanager
def worker_for(use: bool, drawers: int = 1):
    """A drawing worker for the block when ``use`` (the pipeline's decision: :func:`when_to_start`) and one
    can be started, with ``drawers`` processes; the figures of :func:`draw` go to it. Stopped at the
    end of the block, whatever ends it. The worker of :func:`early_worker`, when one runs with as
    many drawers, is the one taken; any other is stopped."""
    worker = _take_early(drawers) if use else None
    discard_early_worker()
    if use and worker is None:
        try:
            worker = Worker(drawers)
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


def _take_early(drawers: int) -> Worker | None:
    worker = _early.pop() if _early else None
    if worker is not None and (len(worker.threads) != drawers or worker.process.poll() is not None):
        worker.stop()  # not the worker asked for, or ended already: a new one
        return None
    if worker is not None:
        worker.unpark()
    return worker


def discard_early_worker() -> None:
    """Stop the worker of :func:`early_worker` that the pipeline did not take (its run took none, or
    one later)."""
    while _early:
        _early.pop().stop()


# A command whose image_points.csv has this many bytes starts its drawing worker (with DRAWERS_NOW
# drawers) as soon as it knows its project folder, before the pipeline's imports and the reading
# (early_worker): from about 4,000 measurements, below which a run takes no worker unless its
# tracks are long (when_to_start), up to about LATER_FROM (lines of 45-65 bytes). The pipeline then
# takes it when it decides "now" (worker_for) and stops it otherwise; the bytes only decide when
# to start, never whether figures are drawn elsewhere.
EARLY_BYTES = (256 * 2**10, 2 * 2**20)


@contextlib.contextmanager
def early_worker(project_dir):
    """Start the drawing worker before the project is read, for a run that will most likely start
    one "now" (EARLY_BYTES of plate measurements, at least two threads for its chunks): its import of
    matplotlib (0.5 s) then runs beside the pipeline's imports and the reading, and it is ready when
    the adjustment asks for its first figures (the close-range block's command: the figures of its
    tests drawn 0.05 s sooner). Whatever the pipeline did not take is stopped at the end of the
    block."""
    from ..solvers.threads import chunk_threads

    try:
        size = os.stat(os.path.join(os.fspath(project_dir), "image_points.csv")).st_size
    except (OSError, TypeError, ValueError):
        size = -1
    if not _current and not _early and chunk_threads() >= 2 and EARLY_BYTES[0] <= size <= EARLY_BYTES[1]:
        try:
            _early.append(Worker(DRAWERS_NOW))
        except Exception:  # no process can be started here: the pipeline decides as without
            pass
    try:
        yield
    finally:
        discard_early_worker()


def park_worker() -> None:
    """Start the drawer of a "later" run now, parked before its import of matplotlib (Worker's
    ``parked``), for :func:`worker_for` to take after the tests: for a run in which only the tables
    come after the tests (the bundle method, whose points come with them), too short to hide the
    whole start of a drawer. It saves the interpreter's start, about 0.1 s of the wait for the
    figures, for 15 MB beside the run (docs/decisions.md "The drawer parked")."""
    if not _current and not _early:
        try:
            _early.append(Worker(1, parked=True))
        except Exception:  # no process can be started here: worker_for starts one or draws here
            pass


# From this many plate measurements on, the worker starts after the gross-error tests: the run's own
# peaks of memory (the iterations, the tests) are behind, and the point precision and the tables
# take long enough for its import. Below, it starts with the run: the worker's 65-100 MB beside a
# small run's memory, and no phase after the tests long enough to hide its import.
LATER_FROM = 50_000
# A run that starts its worker "now" (a small one) waits at its end for the figures of its tests,
# asked for together: two drawers share them (the second a fork of the first once matplotlib is
# imported, so the import is paid once). Close range, ten alternating pairs: 1.57 -> 1.49 s
# (medians). A large run ("later") is not kept waiting by its figures, and a twin's resident
# memory would count a second time.
DRAWERS_NOW = 2


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


def _serve(jobs, results, twins: list[tuple[int, int]]) -> None:  # pragma: no cover - runs in the worker process
    """The drawer: import what the figures need, fork a twin for each line in ``twins`` (its jobs'
    and answers' descriptors), say it is ready (its pid), then draw every job until its input ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is the command's to handle
    from .figures import import_figure_modules

    import_figure_modules(without_axes3d=True)
    mine = (jobs, results)
    for jobs_fd, answers_fd in twins:
        try:
            pid = os.fork()
        except OSError:  # no twin: its line ends, and this drawer takes its figures
            pid = -1
        if pid == 0:  # the twin: its own line only (not the drawer's input, which is fd 0 too)
            for stream in mine:
                stream.close()
            nothing = os.open(os.devnull, os.O_RDONLY)
            os.dup2(nothing, 0)
            os.close(nothing)
            for fd in {fd for pair in twins for fd in pair} - {jobs_fd, answers_fd}:
                with contextlib.suppress(OSError):  # an earlier twin's, closed already
                    os.close(fd)
            mine = (os.fdopen(jobs_fd, "rb"), os.fdopen(answers_fd, "wb"))
            break
        os.close(jobs_fd)
        os.close(answers_fd)
    jobs, results = mine
    _write(results, pickle.dumps(os.getpid(), protocol=pickle.HIGHEST_PROTOCOL))
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
    arguments = sys.argv[1:]
    if arguments[:1] == [PARKED]:  # wait for unpark (or the command's end) before importing
        arguments = arguments[1:]
        if not sys.stdin.buffer.read(1):
            sys.exit(0)
    _serve(sys.stdin.buffer, answers, [tuple(int(fd) for fd in arg.split(",")) for arg in arguments])
