"""The two kinds of failure a user sees: bad input (exit 2) and explained numerical trouble (exit 1)."""

from __future__ import annotations

import os
from dataclasses import dataclass


class InputError(Exception):
    """Bad input: names the file, the line (1-based, None when the whole file is meant) and the reason."""

    def __init__(self, path, line: int | None, reason: str):
        self.path = str(path)
        self.line = line
        self.reason = reason
        where = self.path if line is None else f"{self.path}, line {line}"
        super().__init__(f"{where}: {reason}")


class NumericalFailure(Exception):
    """An adjustment that cannot be carried out, explained in a photogrammetrist's words
    (datum defect, divergence, a photograph without enough measurements).

    reason: why, as summary.json's "termination" names it (core.result.TERMINATIONS: "diverged",
    "datum_defect", "singular", "not_finite", "iteration_limit"), or "failed" for the failures that
    are none of those (too few observations, an unsuitable option)."""

    def __init__(self, message: str, reason: str = "failed"):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Note:
    """Something in the input that striptri did not use, or used in a way the user may not expect
    (a control point no photo measures, an unknown column, a file it does not read). Never silent:
    the pipeline prints every note on stderr (``striptri: warning: ...``), lists it in report.html
    and in summary.json's ``warnings``.

    path: the file (or folder) concerned; line: 1-based, None for the whole file; text: what was
    ignored and why, in a photogrammetrist's words.
    """

    path: str
    line: int | None
    text: str

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}, line {self.line}"
        return f"{where}: {self.text}"


class Interrupted(BaseException):
    """A termination signal (SIGTERM, SIGHUP) received while a command runs, raised where the
    program is so that every ``finally`` and the output reservation clean up (like
    KeyboardInterrupt for SIGINT). A BaseException: no ``except Exception`` may swallow it."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(signum)


# an import runs in these frames (module code, and the Python code a compiled module's initialisation calls)
_IMPORT_FRAMES = ("<frozen importlib._bootstrap>", "<frozen importlib._bootstrap_external>")
REDELIVERY_DELAY_S = 0.01


def deferred_while_importing(signum: int, frame) -> bool:
    """For a signal handler that raises (Interrupted, KeyboardInterrupt): True when the main thread
    is importing a module (``frame``, the interrupted frame, runs inside importlib), after arranging
    for the signal to be sent again REDELIVERY_DELAY_S later; the handler then returns without
    raising and the import goes on.

    An exception raised inside an import leaves the module half-initialised, and a compiled module so
    left may not be importable again (docs/decisions.md "A signal during an import is raised after
    it"): a SIGTERM as orjson's initialisation imported zoneinfo ended the command with a
    segmentation fault at the CSV writer's next ``import orjson``; one as numpy's core imported
    datetime became an ImportError, and the next ``import numpy`` a traceback. Sent again once the
    import has ended, the signal interrupts the command where it can clean up: the command still
    ends with its message and 128 + the signal's number, a moment later (an import takes
    milliseconds, matplotlib's 0.5 s)."""
    while frame is not None:
        if frame.f_code.co_filename in _IMPORT_FRAMES:
            break
        frame = frame.f_back
    else:
        return False
    send_again_later(signum)
    return True


def send_again_later(signum: int) -> None:
    """Send this process the signal ``signum`` again REDELIVERY_DELAY_S from now, from a thread of
    its own (``_thread``, built in: no import, which may be what the signal interrupted)."""
    import _thread

    _thread.start_new_thread(_send_again, (signum,))


def _send_again(signum: int) -> None:
    import time

    time.sleep(REDELIVERY_DELAY_S)
    os.kill(os.getpid(), signum)
