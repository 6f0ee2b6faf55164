"""Work on the other core while CHOLMOD factorises (docs/decisions.md "CHOLMOD without the
interpreter lock").

The ``cholmod`` solver's factorisation runs in C without the GIL (:mod:`.cholmod_direct`) on one
core; meanwhile the rest of an adjustment waits for it. A :class:`BesideTask` is work that does not
need the factor (the selected inversion's symbolic analysis, which needs only N's pattern) done on
a thread in those windows only: its function calls ``pause`` between steps, which returns at once
while a factorisation runs (:func:`factorising`) and waits otherwise. Outside the windows the task
would take the interpreter from the adjustment's own threads (the chunks of a sweep), so it waits;
the numbers it computes are those it would compute on the calling thread.

When the task's result is wanted (:meth:`BesideTask.result`) it runs on without pauses until done;
one that never started is computed there. A task that raises is as if it had not run: ``result``
answers None and the caller computes the thing itself.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Any, Callable

_window_count = 0  # factorisations running now (of any thread)
_tasks: set = set()  # the tasks not done yet
_lock = threading.Lock()


@contextlib.contextmanager
def factorising():
    """The block runs C code without the GIL: tasks waiting in ``pause`` may go on meanwhile."""
    global _window_count
    with _lock:
        _window_count += 1
        for task in _tasks:
            task._go.set()
    try:
        yield
    finally:
        with _lock:
            _window_count -= 1
            if _window_count == 0:
                for task in _tasks:
                    if not task._wanted:
                        task._go.clear()


class Cancelled(Exception):
    """Raised in a task's ``pause`` when the task is no longer wanted."""


class BesideTask:
    """``fn(*args, pause=pause)`` on a daemon thread, going on only in the windows of
    :func:`factorising` (module doc). ``fn`` calls ``pause()`` between short steps."""

    def __init__(self, fn: Callable[..., Any], *args):
        self._fn, self._args = fn, args
        self._go = threading.Event()  # set in a window, or for good once the result is wanted
        self._wanted = self._cancelled = False
        self._done = threading.Event()
        self._value = None
        with _lock:
            _tasks.add(self)
            if _window_count:
                self._go.set()
        threading.Thread(target=self._run, name="striptri-beside", daemon=True).start()

    def pause(self) -> None:
        self._go.wait()
        if self._cancelled:
            raise Cancelled

    def _run(self) -> None:
        try:
            self.pause()  # not even the first step outside a window
            self._value = self._fn(*self._args, pause=self.pause)
        except Exception:  # noqa: BLE001 - the caller computes it itself (module doc)
            self._value = None
        finally:
            self._fn = self._args = None  # what it read may go
            with _lock:
                _tasks.discard(self)
            self._done.set()

    def result(self):
        """The function's value (None if it raised or was cancelled), waiting for it to finish."""
        with _lock:
            self._wanted = True
            self._go.set()
        self._done.wait()
        return self._value

    def cancel(self) -> None:
        """No longer wanted: the thread ends at its next pause."""
        with _lock:
            self._cancelled = True
            self._go.set()

    @property
    def done(self) -> bool:
        return self._done.is_set()
