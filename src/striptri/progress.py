"""Progress of long runs on stderr (docs/decisions.md, "Progress of long runs").

The adjustment loops and the pipeline announce what they finish: each outer iteration (v^T P v,
the correction in units of its standard deviation, seconds, the inner sweeps of an iterative
solver) and each phase after the adjustment (reliability measures, point precision, tables,
report); the iterative solvers announce their inner iterations while they run. They call
:func:`iteration`, :func:`phase` and :func:`inner`, which do nothing unless a
reporter is active in the calling context (:func:`reporting`; the command line makes one unless
``--quiet``), so the library, the tests and the study workers stay silent.

:class:`StderrProgress` shows nothing for the first ``after`` seconds of a run (a short run stays
silent: its stderr is empty when all is well), then the events so far and every later one: on a
terminal as one status line that tqdm rewrites in place, with the finished phases written above
it; otherwise (a log file, a pipe) as plain lines.
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import os
import sys
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the solvers report their inner iterations here: no import at run time
    from .solvers.info import SolverInfo

PROGRESS_AFTER_S = 2.0  # a run shorter than this prints no progress (STRIPTRI_PROGRESS_AFTER overrides)
INNER_EVERY_S = 0.5  # inner sweeps: the terminal's status line is rewritten at most this often
INNER_LINE_EVERY_S = 10.0  # and a plain line (a log) written at most this often

_current: contextvars.ContextVar = contextvars.ContextVar("striptri_progress", default=None)


def iteration(method: str, number: int, vtpv: float, max_correction: float, seconds: float,
              solver_info: SolverInfo | None = None) -> None:
    """An outer iteration has finished (no-op without an active reporter)."""
    reporter = _current.get()
    if reporter is not None:
        reporter.iteration(method, number, vtpv, max_correction, seconds, solver_info)


def inner(solver: str, iterations: int, relative_residual: float) -> None:
    """An iterative solver is in its inner iterations (called every few of them; no-op without an
    active reporter, which shows it at most every INNER_EVERY_S on a terminal, INNER_LINE_EVERY_S in
    a log)."""
    reporter = _current.get()
    if reporter is not None:
        reporter.inner(solver, iterations, relative_residual)


def phase(name: str, seconds: float) -> None:
    """A phase of the run has finished (no-op without an active reporter)."""
    reporter = _current.get()
    if reporter is not None:
        reporter.phase(name, seconds)


@contextlib.contextmanager
def reporting(reporter):
    """Make ``reporter`` receive the events of the code run inside the block (this context only)."""
    token = _current.set(reporter)
    try:
        yield reporter
    finally:
        _current.reset(token)
        reporter.close()


def _number(x: float, spec: str) -> str:
    return format(x, spec) if x is not None and math.isfinite(x) else "n/a"


def iteration_text(method: str, number: int, vtpv: float, max_correction: float, seconds: float,
                   solver_info: SolverInfo | None) -> str:
    text = (f"{method} iteration {number}: vTPv {_number(vtpv, '.6g')}, correction "
            f"{_number(max_correction, '.3g')} sigma, {seconds:.2f} s")
    inner = solver_info.inner_iterations if solver_info is not None else None
    if inner is not None:
        text += f", {inner} inner sweeps"
    return text


class StderrProgress:
    """The command line's reporter (module doc). ``stream``: where to write (stderr); ``after``:
    seconds of silence at the start; ``tty``: terminal or not (default: ``stream.isatty()``)."""

    def __init__(self, stream=None, after: float | None = None, tty: bool | None = None):
        self.stream = stream if stream is not None else sys.stderr
        if after is None:
            after = float(os.environ.get("STRIPTRI_PROGRESS_AFTER", PROGRESS_AFTER_S))
        self.after = after
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty and isatty()) if tty is None else tty
        self.start = time.perf_counter()
        self.pending: list[tuple[str, str]] = []  # events of the silent start: (kind, text)
        self.bar = None
        self.last_inner = -math.inf

    def _showing(self) -> bool:
        return time.perf_counter() - self.start >= self.after

    def iteration(self, method, number, vtpv, max_correction, seconds, solver_info) -> None:
        self._event("iteration", iteration_text(method, number, vtpv, max_correction, seconds, solver_info))

    def phase(self, name, seconds) -> None:
        self._event("phase", f"{name}: {seconds:.2f} s")

    def inner(self, solver, iterations, relative_residual) -> None:
        """Inner sweeps: transient, shown (throttled) only once the silent start is over and
        never queued for later."""
        now = time.perf_counter()
        every = INNER_EVERY_S if self.tty else INNER_LINE_EVERY_S
        if not self._showing() or now - self.last_inner < every:
            return
        self.last_inner = now
        for kind, text in self.pending:
            self._show(kind, text)
        self.pending = []
        self._show("iteration", f"{solver}: inner iteration {iterations}, relative residual "
                                f"{_number(relative_residual, '.1e')}")

    def _event(self, kind: str, text: str) -> None:
        self.pending.append((kind, text))
        if not self._showing():
            return
        for kind, text in self.pending:
            self._show(kind, text)
        self.pending = []

    def _show(self, kind: str, text: str) -> None:
        if not self.tty:
            print(f"striptri: {text}", file=self.stream, flush=True)
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(file=self.stream, bar_format="striptri: {desc} [{elapsed}]", leave=False)
        if kind == "iteration":
            self.bar.set_description_str(text)
        else:
            self.bar.write(f"striptri: {text}", file=self.stream)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
